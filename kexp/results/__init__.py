"""The results room: what happens to runs after the experiment command wrote them.

- :mod:`~kexp.results.aggregate`: a sweep folder's runs as rows (the one place run folders are read back);
  :class:`~kexp.results.aggregate.ReportError`, the one-line error of every results tool.
- :mod:`~kexp.results.report`: ``kexp-report``, a sweep's summary table and figures.
- :mod:`~kexp.results.csvfiles`: the committed results CSVs (``results/<system>_<config>.csv``): columns, names,
  checks (``read_csv``), ``collect``; the reading layer every module below uses.
- :mod:`~kexp.results.table`, :mod:`~kexp.results.robustness`, :mod:`~kexp.results.plants_view`,
  :mod:`~kexp.results.reproduce`: the results, robustness and plants tables; re-running committed rows.
- :mod:`~kexp.results.cli`: ``kexp-results``' argument parsing and dispatch, the only module that imports the others.

Imports run one way (tests/test_structure.py): cli → {table, robustness, plants_view, reproduce} → csvfiles →
aggregate; nothing here imports :mod:`kexp.app` (the experiment command), which imports nothing from here.
"""
