"""The adapter conformance suite: the checks of the adapter contract (``freebody.adapters.base``)
as a pytest base class, for freebody's own engines and for a third-party package's tests.

    # tests/test_conformance.py of a package that ships an adapter
    from freebody.testing import AdapterConformance

    class TestMyEngine(AdapterConformance):
        engine = "myengine"      # the registered name (ENGINES entry or entry point)

Plain pytest collects the subclass (no conftest needed): the class's own
``pytest_generate_tests`` parametrises every check that takes ``offer`` over the
(integrator, precision) pairs the engine offers (``offered_integrators()``, ``precisions``), read
from the adapter class at collection.  A missing engine is a visible skip with its install hint;
a broken one fails.  An engine's opt-in integrators (``Adapter.opt_in_integrators``, its slow
ones) carry the ``slow`` mark.  A subclass may override :meth:`AdapterConformance.adapter_class`
(an adapter class not loaded through the registry; the fake engines of freebody's tests do).

Checked, in the canonical convention (``reference_impl/conventions.py``; q and -q compare equal):

- capabilities well formed (names, integrators, precisions, declared members the harness reads);
- t = 0 read-back on a rotated, offset, moving body with a full inertia tensor;
- one-step pushes (force at a world point, at a body point, world couple, body couple): the change
  of L and p is the impulse of the load;
- a blow-up run through the harness is ``diverged`` with the trajectory up to it;
- ``settings`` entries are {"default", "set"}, JSON-serialisable, and recorded in the run's result;
- offered precisions build, an unoffered precision or integrator raises ``UnsupportedOption``;
- chunked stepping (``simulate(n, chunk_steps=c)``, several ``advance`` calls) equals one-shot
  stepping bit for bit, across load switches;
- ``advance`` moves ``k`` by ``steps`` and returns steps + 1 samples at t = (k0 + i) dt;
- batched stepping (engines with ``supports_batch``) equals one-shot stepping to round-off;
- ``bare_loop`` is None or a callable that runs.
"""
from __future__ import annotations

import contextlib
import json
from typing import ClassVar, NamedTuple

import numpy as np
import pytest

from freebody.adapters.base import (Adapter, BatchRun, EngineMissing, UnsupportedOption,
                                    install_hint, is_available, load_adapter, registry)
from freebody.adapters.capture import capture_output
from freebody.reference_impl.conventions import Trajectory, angular_momentum, linear_momentum
from freebody.reference_impl.problem import Load, Problem
from freebody.reference_impl.rotations import matrix_from_quat, quat_from_rotvec
from freebody.reference_impl.sampling import LOAD_SAMPLINGS
from freebody.run import PRECISIONS, RunSpec, execute

from .helpers import full_inertia, general_problem

# --- tolerances ---------------------------------------------------------------------------------
# t = 0 read-back: the state just written, through the engine's own conversions (quaternion order,
# body-frame w and back): round-off of a few operations on values of order 1 (measured <= 9e-16)...
READBACK_ATOL = {"float64": 1e-12,
                 # ...and float32 storage (eps 1.2e-7) of values up to ~3 (measured 5e-8 for mjx).
                 "float32": 1e-6}
# One push of h = 1e-3 from angular rest, loose: L changes by h tau up to O(h |w+|) (the body turns
# during the step) and, for a force at a fixed world point on a map that evaluates loads within
# the step (RK4 stages), O(h |v| / |r - x|) = 2e-3 as the COM moves under the arm (measured 7e-4,
# reference rk4; <= 6e-7 elsewhere); float32 adds eps32 |p0| / |h f| (measured 5e-6)...  A wrong
# arm, frame or sign is an O(1) error.
# ...except in an engine whose velocities are differences of float32 positions (brax positional:
# v = (x+ - x) / h, w = 2 vec(q+ q^-1) / h), which resolves them only to ~eps32 |x| / h and
# 2 eps32 / h: 2.4e-4 m/s and 1.2e-4 rad/s here, measured 4.3e-2 of h |f| and 4.9e-2 of |h tau|;
# Newton vbd, w = Log(q+ q^-1) / h of float32 quaternions: 5.8e-2 of |h tau|.
PUSH_RTOL = {"float64": 1e-2, "float32": 1e-1}
# Divergence times are sample times t_k = k dt: compared with the trajectory's own t to this slack
# (s; the round-off of k dt).
SAMPLE_TIME_ATOL = 1e-12
# Batched vs alone, BATCH_STEPS = 30 steps of non-chaotic motion at dt 0.01: a vectorised kernel
# (jax.vmap in mjx) may order operations differently, so the two agree to round-off per step,
# relative to each array's scale (measured ~1e-15 in float64, ~1e-7 in float32 for mjx).
BATCH_ROUNDOFF = {"float64": 1e-12, "float32": 1e-4}

# --- the problems ---------------------------------------------------------------------------------
PUSH_DT = 1e-3  # s: one step of the push tests
DT = 0.01  # s: the other tests' step (the switching loads below are placed on its grid)
ADVANCE_STEPS = (5, 1, 8)  # consecutive advance() calls
CHUNKED_STEPS = 90  # one run: loads switch at steps 3, 5, 8, 12, 17, then a 73-step free stretch
CHUNK_SIZES = (1, 7, 32, CHUNKED_STEPS - 1, CHUNKED_STEPS + 3)  # 1, odd sizes, one piece
SPLIT_AT = (17, 40)  # simulate() called three times: steps 0-17, 17-57, 57-90
BATCH_STEPS = 30
F_PUSH = np.array([0.0, 3.0, -2.0])  # N, world
TAU_PUSH = np.array([0.8, -1.5, 0.6])  # N m (world or body frame)
ARM_BODY = np.array([0.5, 0.2, -0.3])  # m, body frame: where the pushes act
# A huge spin near the intermediate axis of I = diag(1, 2, 3), h |w| = 5: explicit gyroscopic
# terms blow up within 2 s (measured: MuJoCo Euler and RK4, every MJX integrator, PyBullet
# multibody, DART, reference euler-matrix and semi-implicit-explicit-gyro); maps that keep L or
# damp the spin stay bounded (a skip, after checking the run is finite).
BLOWUP_W = (0.1, 50.0, 0.0)  # rad/s, world
BLOWUP_DT = 0.1  # s
BLOWUP_DURATION = 5.0  # s

# The conformance body: a full inertia tensor (principal moments 0.9, 1.6, 2.1 kg m^2 in axes
# turned by (-0.3, -0.2, 0.5) rad), rotated, offset, moving and spinning.
CONFORMANCE_BODY = dict(mass=1.7, I_body=full_inertia((0.9, 1.6, 2.1), (-0.3, -0.2, 0.5)),
                        x=(1.5, -2.0, 0.75), q=quat_from_rotvec(np.array((0.4, -0.7, 0.25))),
                        v=(0.3, -0.4, 1.2), w=(0.7, -1.1, 2.3))


def conformance_problem(loads=(), gravity=(0.0, 0.0, -9.81), steps=1, **overrides) -> Problem:
    """The conformance body (:data:`CONFORMANCE_BODY`, any part overridden) over ``steps`` of DT."""
    return general_problem(loads, gravity=gravity, steps=steps, dts=(DT,), name="conformance",
                           **{**CONFORMANCE_BODY, **overrides})


# Loads switching on and off during CHUNKED_STEPS steps of DT (steps 3..11, 5..11, 8..16, all off
# from 17): a body-point force, a world-point force, a world and a body couple.
SWITCHING_LOADS = (
    Load(force=[0.5, -1.0, 2.0], body_point=[0.1, 0.2, -0.3], start=0.03, end=0.12),
    Load(force=[1.0, 0.3, -0.2], point=[2.0, -1.5, 0.9], start=0.05, steps=7),
    Load(torque=[0.05, 0.0, -0.1], body_torque=[0.1, -0.2, 0.3], start=0.08, end=0.17),
)


def switching_problem() -> Problem:
    return conformance_problem(SWITCHING_LOADS, steps=CHUNKED_STEPS)


def batch_problems() -> list[Problem]:
    """Bodies of one structure that differ in every number: mass, inertia, state, gravity, loads."""
    return [
        switching_problem(),
        general_problem((Load(torque=[0.2, 0.1, 0.0], start=0.05, steps=4),),
                        gravity=(0.0, 0.0, 0.0), steps=BATCH_STEPS, name="batch-1", mass=0.6,
                        I_body=full_inertia((1.0, 2.0, 2.5), (0.4, -0.1, -0.9)), x=(0.0, 0.0, 0.0),
                        q=quat_from_rotvec(np.array((1.2, 0.3, -0.2))), v=(0.0, 1.0, 0.0),
                        w=(3.0, 0.2, -1.0)),
        general_problem(gravity=(0.0, -1.0, 0.0), steps=BATCH_STEPS, name="batch-2", mass=2.5,
                        I_body=np.diag([1.0, 2.0, 3.0]), x=CONFORMANCE_BODY["x"],
                        q=quat_from_rotvec(np.zeros(3)), v=CONFORMANCE_BODY["v"], w=(0.01, 5.0, 0.0)),
    ]


def blowup_problem() -> Problem:
    return general_problem(gravity=(0.0, 0.0, 0.0), duration=BLOWUP_DURATION, dts=(BLOWUP_DT,),
                           name="conformance-blowup", mass=1.0, I_body=np.diag([1.0, 2.0, 3.0]),
                           x=(0.0, 0.0, 0.0), q=(1.0, 0.0, 0.0, 0.0), v=(0.0, 0.0, 0.0), w=BLOWUP_W)


PUSHES = ("force at a world point", "force at a body point", "world couple", "body couple")


def push_problem(kind: str) -> tuple[Problem, np.ndarray, np.ndarray]:
    """(problem, expected change of p (3,) N s, expected change of L (3,) N m s) over one step."""
    body = {**CONFORMANCE_BODY, "w": (0.0, 0.0, 0.0)}  # angular rest: no gyroscopic change of L
    x0, R0 = np.asarray(body["x"]), matrix_from_quat(body["q"])
    h, zero = PUSH_DT, np.zeros(3)
    if kind == "force at a world point":
        load = Load(force=F_PUSH, point=x0 + R0 @ ARM_BODY, start=0.0, steps=1)
        dp, dL = h * F_PUSH, h * np.cross(R0 @ ARM_BODY, F_PUSH)  # h (r - x) x f
    elif kind == "force at a body point":
        load = Load(force=F_PUSH, body_point=ARM_BODY, start=0.0, steps=1)
        dp, dL = h * F_PUSH, h * np.cross(R0 @ ARM_BODY, F_PUSH)
    elif kind == "world couple":
        load = Load(torque=TAU_PUSH, start=0.0, steps=1)
        dp, dL = zero, h * TAU_PUSH
    else:
        load = Load(body_torque=TAU_PUSH, start=0.0, steps=1)
        dp, dL = zero, h * R0 @ TAU_PUSH
    pb = general_problem((load,), gravity=(0.0, 0.0, 0.0), steps=1, dts=(h,),
                         name="conformance-push", **body)
    return pb, dp, dL


# --- trajectories ---------------------------------------------------------------------------------

FIELDS = ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity",
          "orthonormality_error")


def assert_identical(a: Trajectory, b: Trajectory, what: str) -> None:
    """Every array of two trajectories equal bit for bit (np.array_equal)."""
    __tracebackhide__ = True
    assert len(a) == len(b), f"{what}: {len(a)} vs {len(b)} samples"
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        if x is None or y is None:
            assert x is None and y is None, f"{what}: {f} present in one trajectory only"
            continue
        if not np.array_equal(x, y):
            bad = np.flatnonzero(np.any((x != y).reshape(len(x), -1), axis=1))
            diff = float(np.max(np.abs(x - y)))
            pytest.fail(f"{what}: {f} differs from sample {bad[0]} on ({len(bad)} samples, "
                        f"max |diff| {diff:.3g})")


def quat_distance(q: np.ndarray, r: np.ndarray) -> float:
    """max |q - r| with q and -q equal."""
    return float(min(np.max(np.abs(q - r)), np.max(np.abs(q + r))))


def assert_valid_samples(tr: Trajectory, steps: int, k0: int, dt: float) -> None:
    __tracebackhide__ = True
    assert len(tr) == steps + 1, f"{len(tr)} samples for {steps} steps"
    assert np.array_equal(tr.t, (k0 + np.arange(steps + 1)) * dt), (tr.t[:3], k0, dt)
    for f, shape in (("position", 3), ("quaternion_wxyz", 4), ("linear_velocity", 3),
                     ("angular_velocity", 3)):
        a = getattr(tr, f)
        assert a.shape == (steps + 1, shape) and a.dtype == np.float64, (f, a.shape, a.dtype)


# --- adapters -------------------------------------------------------------------------------------

def engine_adapter_class(engine: str) -> type[Adapter]:
    """The engine's adapter class from the registry; a missing engine skips with its install hint,
    a broken adapter raises its real error (a failure, never a skip)."""
    if not is_available(engine):
        pytest.skip(f"{engine} not installed ({install_hint(engine)})")
    try:
        with capture_output():  # some engines print on import
            return load_adapter(engine)
    except EngineMissing as e:
        pytest.skip(str(e))


@pytest.fixture
def make_adapter():
    """``make_adapter(engine, problem, dt, integrator, precision=None)``: an adapter of ``engine``
    (a registered name, or an adapter class) for the problem, closed after the test; precision
    None is the engine's first offered precision (``precisions[0]``)."""
    made: list[Adapter] = []

    def make(engine: str | type[Adapter], problem: Problem, dt: float, integrator: str,
             precision: str | None = None) -> Adapter:
        cls = engine_adapter_class(engine) if isinstance(engine, str) else engine
        adapter = cls(problem, dt, integrator, cls.precisions[0] if precision is None else precision)
        made.append(adapter)
        return adapter

    yield make
    for adapter in made:
        adapter.close()


class Offer(NamedTuple):
    """One (engine, integrator, precision) the engine offers; integrator None when the adapter
    could not be loaded at collection (the check then loads it: a skip or the real error)."""

    engine: str
    integrator: str | None
    precision: str | None


class AdapterConformance:
    """The conformance checks of one engine: subclass it in a class whose name starts with
    ``Test`` and set :attr:`engine`; pytest runs every ``test_`` method below on that engine (the
    ones taking ``offer`` once per offered integrator and precision).  See the module docstring."""

    engine: ClassVar[str] = ""  # the registered engine name; set by the subclass
    _offers: ClassVar[dict] = {}  # subclass -> its offer parameters (collected once)

    # --- how the suite finds the adapter ----------------------------------------------------------
    @classmethod
    def adapter_class(cls) -> type[Adapter]:
        """The adapter under test: the registered engine's; a missing engine skips with its
        install hint, a broken one fails.  Override to test a class the registry does not load."""
        return engine_adapter_class(cls.engine)

    @classmethod
    def offer_params(cls) -> list:
        """One ``pytest.param(Offer)`` per offered (integrator, precision); one Offer(engine, None,
        None) when the adapter cannot be loaded at collection (each check then skips or fails)."""
        if cls not in AdapterConformance._offers:
            AdapterConformance._offers[cls] = _collect_offers(cls)
        return AdapterConformance._offers[cls]

    def pytest_generate_tests(self, metafunc) -> None:
        """Called by pytest on the test class for each of its checks: ``offer`` parametrised."""
        if not type(self).engine:
            raise TypeError(f"{type(self).__name__}: set engine = \"<name>\" on the subclass of "
                            f"AdapterConformance")
        if "offer" in metafunc.fixturenames:
            metafunc.parametrize("offer", type(self).offer_params())

    def offer_class(self, offer: Offer) -> type[Adapter]:
        cls = self.adapter_class()
        if offer.integrator is None:
            pytest.fail(f"{offer.engine}: the adapter loaded now but not at collection, or its "
                        f"offered_integrators()/precisions failed")
        return cls

    @contextlib.contextmanager
    def built(self, offer: Offer, problem: Problem, dt: float):
        """An adapter for the offer, closed afterwards."""
        adapter = self.offer_class(offer)(problem, dt, offer.integrator, offer.precision)
        try:
            yield adapter
        finally:
            adapter.close()

    def run(self, offer: Offer, problem: Problem, dt: float, steps: int,
            chunk_steps: int | None = None) -> Trajectory:
        with self.built(offer, problem, dt) as a:
            return a.simulate(steps, chunk_steps)

    # --- capabilities -----------------------------------------------------------------------------
    def test_capabilities_are_well_formed(self):
        cls, engine = self.adapter_class(), self.engine
        assert cls.name == engine
        assert cls.import_name == registry()[engine].import_name
        offered = cls.offered_integrators()
        assert offered and set(offered) <= set(cls.integrators), (offered, cls.integrators)
        assert len(set(offered)) == len(offered)
        assert set(cls.selfcheck_integrators()) <= set(offered)
        assert set(cls.opt_in_integrators) <= set(cls.integrators), cls.opt_in_integrators
        assert cls.precisions and set(cls.precisions) <= set(PRECISIONS), cls.precisions
        assert isinstance(cls.engine_version(), str) and cls.engine_version()
        assert all(isinstance(k, str) and isinstance(v, str) for k, v in cls.conventions.items())
        assert cls.compare_with is None or cls.compare_with in registry()
        assert cls.load_sampling in LOAD_SAMPLINGS, cls.load_sampling
        assert cls.step_rotation_cap_rad is None or cls.step_rotation_cap_rad > 0.0
        assert isinstance(cls.supports_batch, bool)
        with cls.output_capture() as captured:
            pass
        assert isinstance(captured.lines, list) and captured.total >= 0

    # --- t = 0 read-back --------------------------------------------------------------------------
    def test_state_read_back_at_t0_is_the_initial_state(self, offer):
        pb = conformance_problem()
        tr = self.run(offer, pb, DT, 1)
        init, tol = pb.initial, READBACK_ATOL[offer.precision]
        assert tr.t[0] == 0.0
        errors = {
            "position": float(np.max(np.abs(tr.position[0] - init.position))),
            "quaternion (q or -q)": quat_distance(tr.quaternion_wxyz[0], init.quaternion_wxyz),
            "linear velocity": float(np.max(np.abs(tr.linear_velocity[0] - init.linear_velocity))),
            "angular velocity": float(np.max(np.abs(tr.angular_velocity[0] - init.angular_velocity))),
        }
        bad = {k: v for k, v in errors.items() if not v <= tol}
        assert not bad, f"read back at t = 0 vs the case (tol {tol:g}): {bad}"

    # --- pushes: impulse of one step --------------------------------------------------------------
    @pytest.mark.parametrize("kind", PUSHES)
    def test_one_step_push_changes_momenta_by_its_impulse(self, offer, kind):
        pb, dp_expected, dL_expected = push_problem(kind)
        tr = self.run(offer, pb, PUSH_DT, 1)
        M, I_b = pb.body.mass, pb.body.I_body
        L = angular_momentum(I_b, tr.quaternion_wxyz, tr.angular_velocity)
        p = linear_momentum(M, tr.linear_velocity)
        dL, dp = L[1] - L[0], p[1] - p[0]
        err_L = float(np.linalg.norm(dL - dL_expected)) / float(np.linalg.norm(dL_expected))
        # p: relative to h |f| (a couple must leave p alone to the same bound)
        err_p = float(np.linalg.norm(dp - dp_expected)) / (PUSH_DT * float(np.linalg.norm(F_PUSH)))
        rtol = PUSH_RTOL[offer.precision]
        assert err_L <= rtol, (f"|dL - dL_expected| / |dL_expected| = {err_L:.2e} (dL {dL}, "
                               f"expected {dL_expected})")
        assert err_p <= rtol, (f"|dp - dp_expected| / (h |f|) = {err_p:.2e} (dp {dp}, "
                               f"expected {dp_expected})")

    # --- blow-up through the harness --------------------------------------------------------------
    def test_blow_up_is_diverged_with_the_trajectory_up_to_it(self, offer):
        self.offer_class(offer)
        pb = blowup_problem()
        out = execute(RunSpec(pb, offer.engine, offer.integrator, BLOWUP_DT, pb.steps(BLOWUP_DT),
                              offer.precision))
        r, tr = out.result, out.trajectory
        assert r.status in ("ok", "diverged"), (r.status, r.message)
        assert tr is not None and len(tr) >= 1
        finite = np.all([np.all(np.isfinite(getattr(tr, f)), axis=-1) for f in FIELDS[1:5]], axis=0)
        if r.status == "ok":
            # stayed bounded: the harness missed nothing non-finite, and this map cannot blow up here
            assert finite.all(), "a run with non-finite samples was judged ok"
            assert r.diverged_at_s is None
            pytest.skip(f"{offer.engine} {offer.integrator} ({offer.precision}) keeps a spin of "
                        f"{np.linalg.norm(BLOWUP_W):g} rad/s at dt = {BLOWUP_DT} bounded: no "
                        f"blow-up to detect")
        t_div = r.diverged_at_s
        assert t_div is not None and 0.0 < t_div <= BLOWUP_DURATION + SAMPLE_TIME_ATOL, r
        assert f"{t_div:.6g}" in r.message, r.message
        assert tr.t[0] == 0.0 and np.allclose(np.diff(tr.t), BLOWUP_DT, rtol=0, atol=SAMPLE_TIME_ATOL)
        assert tr.t[-1] >= t_div - SAMPLE_TIME_ATOL, "the trajectory stops before the divergence"
        before = tr.t < t_div - SAMPLE_TIME_ATOL
        assert before.sum() >= 1
        assert finite[before].all(), "non-finite samples before the divergence"
        # no metric past the blow-up; the ones kept before it are finite numbers or None
        assert r.metrics["orientation_error_max_rad"] is None
        assert r.final_state is None
        json.dumps(r.to_json(), allow_nan=False)

    # --- settings ---------------------------------------------------------------------------------
    def test_settings_are_recorded_and_serialisable(self, offer):
        pb = conformance_problem(SWITCHING_LOADS, gravity=(0.5, -1.0, -3.0), steps=3)
        with self.built(offer, pb, DT) as a:
            settings = a.settings
        assert isinstance(settings, dict)
        for key, entry in settings.items():
            assert isinstance(key, str)
            assert isinstance(entry, dict) and set(entry) == {"default", "set"}, (key, entry)
        text = json.dumps(settings, allow_nan=False)  # raises on numpy types, NaN, inf
        result = execute(RunSpec(pb, offer.engine, offer.integrator, DT, 3, offer.precision)).result
        assert result.status == "ok", result.message
        assert json.loads(json.dumps(result.engine_settings, allow_nan=False)) == json.loads(text)

    # --- precision and integrator offers ----------------------------------------------------------
    def test_offered_precisions_build_and_others_are_refused(self):
        cls = self.adapter_class()
        pb = conformance_problem()
        integrator = cls.offered_integrators()[0]
        for precision in cls.precisions:
            cls(pb, DT, integrator, precision).close()
        for precision in [p for p in PRECISIONS if p not in cls.precisions] + ["float16"]:
            with pytest.raises(UnsupportedOption):
                cls(pb, DT, integrator, precision)
        for bad in ("no-such-integrator", ""):
            with pytest.raises(UnsupportedOption):
                cls(pb, DT, bad, cls.precisions[0])
        not_offered = [i for i in cls.integrators if i not in cls.offered_integrators()]
        for bad in not_offered:  # declared but not in the installed version
            with pytest.raises(UnsupportedOption):
                cls(pb, DT, bad, cls.precisions[0])

    # --- chunked stepping -------------------------------------------------------------------------
    def test_chunked_stepping_equals_one_shot_bit_for_bit(self, offer):
        pb = switching_problem()
        whole = self.run(offer, pb, DT, CHUNKED_STEPS)
        assert_valid_samples(whole, CHUNKED_STEPS, 0, DT)
        for c in CHUNK_SIZES:
            assert_identical(self.run(offer, pb, DT, CHUNKED_STEPS, chunk_steps=c), whole,
                             f"simulate({CHUNKED_STEPS}, chunk_steps={c}) vs simulate({CHUNKED_STEPS})")
        # the pieces chunks() delivers: consecutive, each sample once
        with self.built(offer, pb, DT) as a:
            pieces = list(a.chunks(CHUNKED_STEPS, 7))
        assert [len(p) for p in pieces] == [8] + [7] * 11 + [6]
        assert_identical(Trajectory.concatenate(pieces), whole, "chunks(n, 7) concatenated")
        # a run continued by further simulate() calls
        with self.built(offer, pb, DT) as a:
            parts, k = [], 0
            for stop in (*np.cumsum(SPLIT_AT), CHUNKED_STEPS):
                tr = a.simulate(int(stop) - k)
                parts.append(tr if k == 0 else tr.tail(1))
                k = int(stop)
        assert_identical(Trajectory.concatenate(parts), whole, f"simulate() split at {SPLIT_AT}")

    # --- advance ----------------------------------------------------------------------------------
    def test_advance_moves_k_and_returns_the_samples_from_k(self, offer):
        with self.built(offer, switching_problem(), DT) as a:
            assert a.k == 0
            assert a.dt == DT and a.integrator == offer.integrator and a.precision == offer.precision
            previous = None
            for steps in ADVANCE_STEPS:
                k0 = a.k
                tr = a.advance(steps)
                assert a.k == k0 + steps
                assert_valid_samples(tr, steps, k0, DT)
                if previous is not None:  # the current state first: the last sample handed out
                    assert_identical(tr.head(1), previous.tail(len(previous) - 1),
                                     "advance's first sample")
                previous = tr
            assert a.compile_time_s is None or a.compile_time_s >= 0.0

    # --- batched stepping -------------------------------------------------------------------------
    def test_batched_stepping_equals_one_shot_to_round_off(self, offer):
        cls = self.offer_class(offer)
        if not cls.supports_batch:
            pytest.skip(f"{offer.engine} does not step bodies as a batch")
        problems = batch_problems()
        batch = cls.simulate_batch(problems, DT, BATCH_STEPS, offer.integrator, offer.precision)
        assert isinstance(batch, BatchRun)
        assert len(batch.trajectories) == len(problems)
        assert batch.diverged_at_s == [None] * len(problems)
        assert batch.compile_time_s >= 0.0 and batch.step_time_s >= 0.0
        assert batch.engine_settings == [] or len(batch.engine_settings) == len(problems)
        for i, (pb, tr) in enumerate(zip(problems, batch.trajectories)):
            alone = self.run(offer, pb, DT, BATCH_STEPS)
            assert len(tr) == len(alone), f"batch body {i}: {len(tr)} vs {len(alone)} samples"
            assert np.array_equal(tr.t, alone.t), f"batch body {i}: times differ"
            for f in FIELDS:
                a, b = getattr(tr, f), getattr(alone, f)
                if a is None or b is None:
                    assert a is None and b is None, f"batch body {i}: {f} in one only"
                    continue
                scale = max(1.0, float(np.max(np.abs(b))))
                err = float(np.max(np.abs(a - b)))
                assert err <= BATCH_ROUNDOFF[offer.precision] * scale, (
                    f"batch body {i} vs its run alone: {f} differs by {err:.3g}")
        for i, st in enumerate(batch.engine_settings):
            with self.built(offer, problems[i], DT) as a:
                assert json.loads(json.dumps(st, allow_nan=False)) == json.loads(json.dumps(a.settings))

    # --- bare loop --------------------------------------------------------------------------------
    def test_bare_loop_is_none_or_runs(self, offer):
        with self.built(offer, conformance_problem(), DT) as a:
            loop = a.bare_loop(10)
            if loop is None:
                return
            assert callable(loop)
            loop()


def _collect_offers(cls: type[AdapterConformance]) -> list:
    name = cls.engine
    try:
        adapter = cls.adapter_class()
        integrators, precisions = adapter.offered_integrators(), tuple(adapter.precisions)
        opt_in = tuple(adapter.opt_in_integrators)
    except (Exception, pytest.skip.Exception):  # reported by each check: skip or failure
        return [pytest.param(Offer(name, None, None), id=name)]
    offers = []
    for integ in integrators:
        # opt-in integrators are the engine's slow ones (seconds to minutes a run): marked slow
        marks = [pytest.mark.slow] if integ in opt_in else []
        for prec in precisions:
            offers.append(pytest.param(Offer(name, integ, prec), marks=marks,
                                       id=f"{name}-{integ}-{prec}"))
    return offers
