"""Plants as a user writes them (``plant.kind=python``, ``plant.target=plant_rigs:<Class>``): the classes the plant
tests close loops on.  Each has dt, n, m, reset(x0) and step(u) -> the next state, and nothing of kexp's."""
import numpy as np
from scipy.integrate import solve_ivp


class VdpRig:
    """Van der Pol (ẍ = μ(1 − x²)ẋ − x + u) integrated by scipy's own solve_ivp (DOP853, rtol 1e-10, atol 1e-12)
    over each held step: the physics of kexp's VanDerPol, with no formula kexp can see."""

    n, m = 2, 1

    def __init__(self, dt=0.01, mu=1.0):
        self.dt, self.mu = dt, mu
        self.x = np.zeros(2)

    def reset(self, x0):
        self.x = np.array(x0, dtype=float)

    def step(self, u):
        mu, u0 = self.mu, float(u[0])
        sol = solve_ivp(lambda t, x: [x[1], mu * (1 - x[0] ** 2) * x[1] - x[0] + u0], (0.0, self.dt), self.x,
                        method="DOP853", rtol=1e-10, atol=1e-12)
        self.x = sol.y[:, -1]
        return self.x


class FailingRig(VdpRig):
    """VdpRig whose step raises (``mode='raise'``), returns NaN (``'nan'``) or the wrong shape (``'shape'``) from
    step ``after`` on (counted from the last reset)."""

    def __init__(self, after=5, mode="raise", **kw):
        super().__init__(**kw)
        self.after, self.mode, self.k = after, mode, 0

    def reset(self, x0):
        super().reset(x0)
        self.k = 0

    def step(self, u):
        self.k += 1
        if self.k > self.after:
            if self.mode == "raise":
                raise RuntimeError("the rig's amplifier tripped")
            if self.mode == "nan":
                return np.array([np.nan, 0.0])
            return np.zeros(3)
        return super().step(u)


class LinearRig:
    """ẋ = A x + B u with A = [[0, 1], [2, −1]], B = [0, 1]ᵀ held over Δ, stepped exactly (matrix exponential):
    the discrete linearisation is known, (expm(AΔ), ∫₀^Δ expm(As) ds B)."""

    n, m = 2, 1
    A = np.array([[0.0, 1.0], [2.0, -1.0]])
    B = np.array([[0.0], [1.0]])

    def __init__(self, dt=0.05):
        from scipy.linalg import expm
        self.dt = dt
        big = np.zeros((3, 3))
        big[:2, :2], big[:2, 2:] = self.A * dt, self.B * dt
        e = expm(big)
        self.Ad, self.Bd = e[:2, :2], e[:2, 2:]
        self.x = np.zeros(2)

    def reset(self, x0):
        self.x = np.array(x0, dtype=float)

    def step(self, u):
        self.x = self.Ad @ self.x + self.Bd @ np.asarray(u, dtype=float)
        return self.x


class SleepyRig(VdpRig):
    """VdpRig whose step takes wall-clock time, as a rig's driver does: it sleeps ``sleep`` s every step, and
    ``overrun`` s instead at the steps in ``at`` (counted from 0 after the last reset): the real-time tests' plant
    (a step that overruns its deadline)."""

    def __init__(self, sleep=0.0, overrun=0.0, at=(), **kw):
        super().__init__(**kw)
        self.sleep, self.overrun, self.at, self.k = sleep, overrun, frozenset(at), 0

    def reset(self, x0):
        super().reset(x0)
        self.k = 0

    def step(self, u):
        import time
        pause = self.overrun if self.k in self.at else self.sleep
        self.k += 1
        if pause > 0:
            time.sleep(pause)
        return super().step(u)
