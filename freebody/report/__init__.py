"""Reports: what a results document says, for people.  :mod:`.data` derives the figures (labels,
physics series recomputed from stored states), :mod:`.markdown` and :mod:`.html` render report.md
and report.html, :mod:`.plots` the PNG figures (matplotlib, imported lazily), :mod:`.summary` the
terminal table; :mod:`.render` writes them all for a run folder."""
from .render import finish_run, write_reports
from .summary import summary_table

__all__ = ["finish_run", "write_reports", "summary_table"]
