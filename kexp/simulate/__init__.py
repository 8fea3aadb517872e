from .closed_loop import RunMetrics, RunResult, SimConfig, StepRecord, closed_loop, run_cost

__all__ = ["RunMetrics", "RunResult", "SimConfig", "StepRecord", "closed_loop", "run_cost"]
