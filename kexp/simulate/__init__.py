from .closed_loop import Disturbance, RunMetrics, RunResult, SimConfig, StepRecord, closed_loop, run_cost
from .pacing import Pacer, RealtimeSummary

__all__ = ["Disturbance", "Pacer", "RealtimeSummary", "RunMetrics", "RunResult", "SimConfig", "StepRecord",
           "closed_loop", "run_cost"]
