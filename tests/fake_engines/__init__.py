"""Adapter modules used by the registry tests: real import behaviour of broken or absent engines."""
