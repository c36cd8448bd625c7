"""The bundled case files (TOML), shipped as package data of ``freebody.cases``."""
