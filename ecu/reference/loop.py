"""Float64 twin of the firmware's speed loop in RUN (document reproduction: no limiters, no
robustness): central-difference rate (or the true rate, as the document's simulation had), or
the tracking filter's rate for the control law (rate_filter_on), delayed estimator interval,
MRAC / PID / open loop, reference model. Used by sil.verify and tests."""

from __future__ import annotations

from collections import deque

from ecu.params import CONTROLLERS, CTRL_MRAC, CTRL_OPEN_LOOP, CTRL_PI, CTRL_PID, EcuParams
from ecu.reference.estimator import FloatEstimator
from ecu.reference.mrac import FloatMrac
from ecu.reference.pi import FloatPi
from ecu.reference.pid import FloatPid
from ecu.reference.rate_filter import FloatRateFilter


class FloatLoop:
    """step(n_pct, demand_pct, open_loop_v, true_rate=None) -> pump voltage (V)."""

    def __init__(self, params: EcuParams) -> None:
        self.p = params
        self.ctrl = CONTROLLERS.index(params.controller)
        self.est = FloatEstimator(params)
        self.mrac = FloatMrac(params)
        self.pid = FloatPid(params)
        self.pi = FloatPi(params)
        self.pid.i = self.pi.i = params.entry_v - params.trim_v  # bumpless entry into RUN
        self.u_lag = params.entry_v - params.trim_v  # the MRAC's lagged command
        self.lag_c = (1.0 / params.rate_hz) / (params.mrac_cmd_lag_s + 1.0 / params.rate_hz)
        self.rate_filter = FloatRateFilter(params)
        self.m = max(1, round(params.rate_window_s * params.rate_hz / 2.0))
        self.n_hist: deque[float] = deque(maxlen=2 * self.m + 2)  # newest last
        self.v_hist: deque[float] = deque(maxlen=self.m + 2)  # given true rates
        self.u_hist: deque[float] = deque(maxlen=self.m + 2)
        self.first = True

    def _rate(self, age: int, true_rate: bool) -> float:
        if true_rate:
            return self.v_hist[-1 - age]
        h, m = self.n_hist, self.m
        return (h[-1 - age + m] - h[-1 - age - m]) * self.p.rate_hz / (2 * m)

    def step(
        self, n_pct: float, demand_pct: float, open_loop_v: float, true_rate: float | None = None
    ) -> float:
        p, m = self.p, self.m
        dn = n_pct - p.trim_n_pct
        self.n_hist.append(dn)
        self.v_hist.append(true_rate if true_rate is not None else 0.0)
        self.u_hist.append(0.0)
        use_true = true_rate is not None
        filled = len(self.n_hist) > 2 * m
        if self.first:
            self.mrac.xm1 = dn
            self.rate_filter.start(dn)
            self.first = False
        else:
            e = self.est
            self.rate_filter.step(dn, self.u_hist[-2], (e.lam, e.th1, e.th2))
        rate = true_rate if use_true else (self._rate(m, False) if filled else 0.0)
        if p.rate_filter_on:
            rate = self.rate_filter.v
        if len(self.n_hist) == 2 * m + 2 and len(self.u_hist) == m + 2:
            h = self.n_hist
            self.est.step(
                h[-1 - (m + 1)],
                self._rate(m + 1, use_true),
                h[-1 - m],
                self._rate(m, use_true),
                self.u_hist[-1 - (m + 1)],
                True,
            )
        r = demand_pct - p.trim_n_pct
        if self.ctrl == CTRL_MRAC:
            self.u_lag += self.lag_c * (self.mrac.control(dn, rate, r) - self.u_lag)
            u = self.u_lag
            self.mrac.gain_update(self.est)
        elif self.ctrl == CTRL_PID:
            u = self.pid.control(demand_pct - n_pct, rate)
        elif self.ctrl == CTRL_PI:
            u = self.pi.control(demand_pct - n_pct, n_pct)
        else:
            assert self.ctrl == CTRL_OPEN_LOOP
            u = open_loop_v - p.trim_v
        self.mrac.reference_step(r)
        self.u_hist[-1] = u
        return p.trim_v + u
