from .diff import DiffResult, Divergence, diff_logs
from .reader import LogError, RunLog, read_log
from .writer import RunLogger, copy_log

__all__ = ["DiffResult", "Divergence", "diff_logs", "LogError", "RunLog", "read_log", "RunLogger", "copy_log"]
