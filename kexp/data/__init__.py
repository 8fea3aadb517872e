from .collect import DataConfig, RegionFilter, collect
from .excitation import EXCITATION_KINDS, Excitation
from .dataset import DataReport, Dataset
from .files import DataBounds, DataSource, write_runs
from .streaming import RecordedRuns, open_runs, read_runs
from .integrate import IntegrationFailure, IntegratorOptions, integrate
from .samplers import SAMPLERS, Box, Circle, Points, make_sampler

__all__ = ["DataConfig", "Excitation", "RegionFilter", "collect", "DataReport", "Dataset", "IntegrationFailure",
           "IntegratorOptions", "integrate", "SAMPLERS", "Box", "Circle", "Points", "make_sampler",
           "DataBounds", "EXCITATION_KINDS", "DataSource", "read_runs", "write_runs", "open_runs", "RecordedRuns"]
