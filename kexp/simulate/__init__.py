from .closed_loop import Disturbance, RunMetrics, RunResult, SimConfig, StepRecord, closed_loop, run_cost

__all__ = ["Disturbance", "RunMetrics", "RunResult", "SimConfig", "StepRecord", "closed_loop", "run_cost"]
