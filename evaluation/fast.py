"""The fast engine: the daemon's loop, set up by the daemon's own code (assembly, start, switch,
enable), then cycled by :func:`evaluation.kernel.cycle` with the controller stepped in Python
between two calls. What it takes over is read once from the loop, its rig I/O and its simulated
transport (their attributes, as the set-up left them); tests/test_evaluation.py holds its
trajectories equal to the loop's own.

It runs what an evaluation needs of the loop and refuses the rest (:func:`refusal`): a rig of
cylinder joints with RDC506 position sensors, no chamber transmitters (the controllers would
read pressures), the simulated transport with its compiled plant stepping once a period. Other
inputs (the force sensor) are swept, so the noise follows the same sequence, but not read: the
loop engine checks their plausibility. No shadow, open-loop run, known load or tracking rule.
"""
from __future__ import annotations

import math

import numpy as np

from controllers.base import JointState, Reference, check_output
from evaluation import kernel as K
from evaluation import reference_samples, twin_run, twin_state
from hal.potentiometer import RDC506

_NOISE: dict = {}  # (generator state, count) -> its draws: the controllers compared on one plant and path share them
BLOCK = 4096  # cycles a compiled call runs: the reference is sampled for them beforehand
WHAT = {"position": 0, "first": 1, "second": 2, "force": 3, "supply_pressure": 4, "supply": 5, "constant": 5}


def refusal(loop) -> str:
    """Why the fast engine cannot run this loop ("" when it can)."""
    transport = loop.io.transport
    if getattr(transport, "backend", "") != "sim" or not hasattr(getattr(transport, "arm", None), "_coef"):
        return "the simulated transport with its compiled plant (transport option compiled = true)"
    if abs(transport.options.step_s - loop.period) > 1e-12:
        return "one plant step a period"
    if any(not isinstance(s, RDC506) for _, s in loop.io._positions):
        return "RDC506 position sensors"
    if loop.io._pressure_slots:
        return "a rig without chamber transmitters"
    if loop.tracking.on or loop.shadow_run is not None or loop.feed_forward.load is not None:
        return "no tracking rule, shadow or known load"
    if transport._faults:
        return "no injected fault"
    return ""


class FastLoop:
    """The loop's state taken over after its set-up; :meth:`run` cycles it."""

    def __init__(self, loop, cycles: int, key=None):
        """``cycles``: how many cycles at most will run (the noise is drawn for them beforehand);
        ``key`` names the reference in force (:meth:`set_trajectory`)."""
        why = refusal(loop)
        if why:
            raise ValueError(f"the fast engine needs {why}")
        io, transport, arm, sup = loop.io, loop.io.transport, loop.io.transport.arm, loop.supervisor
        self.loop, self.controller, self.period = loop, loop.controller, loop.period
        self.n, self.width = loop.n, loop.actuation.width
        self.deadline, self.now = loop._deadline, loop.clock.now()
        self.trajectory, self.t0 = loop.trajectory, loop.trajectory_t0
        self.reference = loop.reference
        self.stiffness = list(loop.stiffness)
        self.pressures = loop.snapshot.pressures
        self.u = list(loop.u)
        self.cause = ""
        # a reference's samples kept across cases
        self.samples = None if key is None else reference_samples.kept(key, self.t0)
        n = self.n
        J = np.zeros((n, K.J_WIDTH))
        pairs = {i: (ih, ir) for i, _, ih, _, ir in io._pairs}
        for i, (_, s) in enumerate(io._positions):
            c = s.config
            J[i, K.J_SIG:K.J_THI + 1] = (s._index, s._supply, c.supply_volts, s._angle0, s._gain, c.zero_ratio,
                                         s._lo, s._hi, s._ratio_lo, s._ratio_hi, s._travel_lo, s._travel_hi)
        for k, i, head, bias, rod_pa in loop.actuation._cylinders:
            rod = io.rod[i]
            J[i, K.J_OUT_HEAD], J[i, K.J_OUT_ROD] = pairs[i]
            J[i, K.J_BIAS], J[i, K.J_ROD_PA] = bias, rod_pa
            J[i, K.J_H_SLOPE:K.J_R_PMAX + 1] = (head._slope, head._offset, head._p_min, head._p_max,
                                                rod._slope, rod._offset, rod._p_min, rod._p_max)
        for i, ((lo, hi), w) in enumerate(zip(sup._limits, sup._max_speed)):
            J[i, K.J_QMIN], J[i, K.J_QMAX], J[i, K.J_WMAX] = lo, hi, w
        J[:, K.J_ANGLE], J[:, K.J_VEL] = loop.angles, loop.velocities
        J[:, K.J_PH], J[:, K.J_PR] = loop.p_head, loop.p_rod
        C = np.zeros((len(transport.inputs), K.C_WIDTH))
        for c, ((what, joint, offset, slope), adc) in enumerate(zip(transport._sensing, transport._adc)):
            C[c, :K.C_VALUE] = (WHAT[what], joint, offset, slope, *adc)
        O = np.zeros((len(transport.outputs), K.O_WIDTH))
        for o, (dac, v) in enumerate(zip(transport._dac, transport._out)):
            O[o] = (*dac, v)
        G = np.zeros(K.G_WIDTH)
        G[K.G_PREV_T], G[K.G_FILTER_W] = loop.snapshot.t, loop._filter_w
        G[K.G_STEP_S], G[K.G_T0], G[K.G_SUPPLY_PA] = transport.options.step_s, transport._t0, arm.supply_pa
        G[K.G_P_MAX], G[K.G_DP], G[K.G_SIGMA] = sup._p_max, sup._dp, transport.options.adc_noise_volts
        G[K.G_CONTACT_F], G[K.G_REG:K.G_REG + 5] = arm.contact_force_n, arm._reg
        Kc = np.zeros(K.K_WIDTH, dtype=np.int64)
        Kc[K.K_STEPS], Kc[K.K_BAD_SENSOR], Kc[K.K_BAD_SPEED] = transport._steps, sup._bad_sensor, sup._bad_speed
        Kc[K.K_N_BAD] = sup._n_bad
        self.J, self.C, self.O, self.G, self.K = J, C, O, G, Kc
        self.noise = _noise(transport._rng, len(transport.inputs) * (cycles + 1)) if G[K.G_SIGMA] > 0 else np.zeros(1)
        self.plant = (arm._coef, arm._buf, arm._state, arm._k, np.zeros(n))
        self.U, self.A = np.zeros(self.width + n), np.zeros(2 * n)
        self.twin: twin_state.Twin | None = None  # the controller's compiled twin, once taken
        self.out = np.zeros(self.width)  # its step's output

    def set_trajectory(self, trajectory, key=None) -> None:
        """As :meth:`daemon.loop.controls.LoopControls.set_trajectory`: from the next cycle on.
        ``key`` names the reference (the same key, the same trajectory): its samples are then
        kept for the next case that runs it from the same t0 (the cycles' times are then the
        same floats: every case counts its deadlines from the same start), so the controllers
        compared on one plant and path sample it once."""
        self.trajectory, self.t0 = trajectory, self.now + self.period
        self.reference = trajectory.sample(0.0)
        self.samples = None if key is None else reference_samples.kept(key, self.t0)

    def run(self, cycles: int, log: np.ndarray | None = None) -> bool:
        """``cycles`` cycles (each logged as reference, angles, output into ``log``'s rows when
        given); False after a trip (its cause in :attr:`cause`). A built-in controller steps
        compiled (:mod:`evaluation.twin_run`) from its second step on; the rest in Python."""
        L = np.zeros((0, 2 * self.n + self.width)) if log is None else log
        self.K[K.K_LOG] = -1  # the first row is this run's first cycle: logged from the second call on
        self._first_t = self.deadline
        samples = self.samples if self.samples is not None else reference_samples.Samples()
        done, ok = 0, True
        while ok and done < cycles:
            if self.twin is None:
                count = 1 if twin_state.supported(self.controller) else cycles - done
                ok = self._python(done, count, samples, log is not None, L)
                self.twin = twin_state.after_first_step(self.controller) if ok and count == 1 else None
            else:
                count = min(BLOCK, cycles - done)
                ok = self._compiled(done, count, samples, log is not None, L)
            done += count
        if ok:
            K.log_row(self.J, self.K, self.U, L)
        return ok

    def _python(self, start: int, cycles: int, samples: reference_samples.Samples, logged: bool, L: np.ndarray) -> bool:
        """Cycles ``start``.. of this run with the controller's Python step."""
        J, C, O, G, Kc, noise, U, A = self.J, self.C, self.O, self.G, self.K, self.noise, self.U, self.A
        coef, buf, state, k, tau = self.plant
        cycle, step, width, n, period = K.cycle, self.controller.step, self.width, self.n, self.period
        trajectory, t0, stiffness, pressures = self.trajectory, self.t0, self.stiffness, self.pressures
        deadline, commands, references = self.deadline, range(width), range(n)
        kept, rows = len(samples.rows), samples.rows
        written, logging, last = K.K_WRITE, K.K_LOG, self.now
        for i in range(start, start + cycles):
            now = deadline
            outcome = cycle(now, J, C, O, G, Kc, noise, coef, buf, state, k, tau, U, A, L)
            if outcome:
                self._trip(outcome)
                break
            if i < kept:
                ref = rows[i]
            else:
                ref = trajectory.sample(now - t0)
                samples.sampled(ref, now + period)
            both = A.tolist()
            q = ref[0]
            try:
                u = step(JointState(now, both[:n], both[n:], pressures), Reference(q, ref[1], ref[2], stiffness))
                check_output(u, width)
            except Exception as exc:  # as the loop: a failing controller trips
                self._failed(exc)
                break
            for c in commands:
                U[c] = u[c]
            for j in references:
                U[width + j] = q[j]
            if i == 0:
                Kc[written] = 1  # from the next call on, the kernel writes the output
                if logged:
                    Kc[logging] = 0
            deadline += period
            last = now
        else:
            self.deadline, self.now, self.reference, self.u = deadline, last, ref, list(u)
            return True
        self.deadline, self.now = deadline, last
        return False

    def _compiled(self, start: int, cycles: int, samples: reference_samples.Samples, logged: bool,
                  L: np.ndarray) -> bool:
        """Cycles ``start``.. of this run with the controller's compiled twin: the reference
        sampled for them first (the same times: the same sums of the period)."""
        period = self.period
        samples.extend(start + cycles, self.trajectory, self.t0, self._first_t, period)
        refs = samples.angles[start:start + cycles]
        coef, buf, state, k, tau = self.plant
        tw = self.twin
        done, outcome, now, last = twin_run.run(tw.kind, tw.dob, self.deadline, period, refs, start == 0, logged,
                                                self.J, self.C, self.O, self.G, self.K, self.noise, coef, buf, state,
                                                k, tau, self.U, self.A, L, *tw.arrays(), tw.LIM, self.out)
        if done:
            self.now, self.reference, self.u = last, samples.rows[start + done - 1], self.out.tolist()
        self.deadline = now
        if outcome == twin_run.NOT_FINITE:
            try:
                check_output(self.out.tolist(), self.width)  # raises: the loop's own words for that output
            except ValueError as exc:
                self._failed(exc)
        elif outcome:
            self._trip(outcome)
        return not outcome

    def compile(self) -> None:
        """Compile the twins' loop (:mod:`evaluation.twin_run`) now, running no cycle: done once
        before a pool forks its workers, which then inherit it (else each compiles it, about 15 s
        on a fresh install, or loads it from numba's cache)."""
        tw = twin_state.placeholder(self.n)
        coef, buf, state, k, tau = self.plant
        twin_run.run(tw.kind, tw.dob, self.deadline, self.period, np.zeros((0, self.n)), False, False, self.J, self.C,
                     self.O, self.G, self.K, self.noise, coef, buf, state, k, tau, self.U, self.A,
                     np.zeros((0, 2 * self.n + self.width)), *tw.arrays(), tw.LIM, self.out)

    def _failed(self, exc: Exception) -> None:
        """The cause of a trip by a failing step, in the loop's words."""
        self.cause = f"controller {self.controller.name} failed: {type(exc).__name__}: {exc}"

    def _trip(self, outcome: int) -> None:
        code, i = divmod(outcome, 16)
        joint = self.loop.rig.joints[i]
        if code == K.SENSOR_TRIP:
            label, sensor = self.loop.io._positions[i]
            fault = sensor.fault(self.C[:, K.C_VALUE].tolist())
            self.cause = f"{label}: {fault} ({self.K[K.K_BAD_SENSOR]} samples in a row)"
        elif code == K.LIMIT_TRIP:
            self.cause = f"joint {joint.name} at {joint.shown(self.J[i, K.J_ANGLE])} is outside its limits " \
                         f"{joint.shown_limits()}"
        else:
            self.cause = f"joint {joint.name} moving at {joint.shown(self.J[i, K.J_VEL], True)}, " \
                         f"over its {joint.shown(joint.max_speed, True)} limit"


def _noise(rng, count: int) -> np.ndarray:
    """The next ``count`` values ``rng.gauss(0, 1)`` would give (``rng``: a ``random.Random``):
    its Mersenne Twister state in numpy's, whose doubles are CPython's (genrand_res53). Kept
    for the next case whose generator is in the same state (the set-up draws the same numbers
    whatever the controller): read only by the kernel."""
    key = (rng.getstate(), count)
    if key not in _NOISE:
        while len(_NOISE) >= 2:
            del _NOISE[next(iter(_NOISE))]
        _NOISE[key] = _draw(*key)
    return _NOISE[key]


def _draw(state, count: int) -> np.ndarray:
    """:func:`_noise`'s draws from the generator's ``state``."""
    version, internal, pending = state
    mt = np.random.RandomState()
    mt.set_state(("MT19937", np.array(internal[:-1], dtype=np.uint32), internal[-1], 0, 0.0))
    first = math.nan if pending is None else pending
    draws = count - (0 if pending is None else 1)
    uniforms = mt.random_sample(2 * ((max(draws, 0) + 1) // 2))
    return K.gauss_pairs(uniforms, first)
