"""The experiment room: the ``kexp`` command, from a Hydra config to a run folder.

- :mod:`~kexp.app.main` (the command; :mod:`~kexp.app.help`, :mod:`~kexp.app.precheck` before Hydra runs),
  :mod:`~kexp.app.conf`, :mod:`~kexp.app.confdir`, :mod:`~kexp.app.schema` (the configs and their schema),
  :mod:`~kexp.app.build` (a config into typed objects), :mod:`~kexp.app.budget` (sizes refused before work).
- :mod:`~kexp.app.experiment`: one run, as its stages (prepare → identify → certify → controller → log → closed
  loop → record → finish); :mod:`~kexp.app.data_only` (``system=data``), :mod:`~kexp.app.cache` (models and CLFs
  kept between runs), :mod:`~kexp.app.progress`.
- The run folder and its safety: :mod:`~kexp.app.run_folder`, :mod:`~kexp.app.faults`, :mod:`~kexp.app.lock`,
  :mod:`~kexp.app.golden`.
- Sweeps in the ``kexp`` process: :mod:`~kexp.app.sweeper`, :mod:`~kexp.app.resume`, :mod:`~kexp.app.sweep_progress`.

What happens to run folders afterwards (tables, reports, re-runs) is :mod:`kexp.results`; the two rooms do not
import each other (tests/test_structure.py).
"""
