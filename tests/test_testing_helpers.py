"""freebody.testing: the helpers for an engine's tests, and the shipped conformance class used the
way a third-party package uses it (a test file of its own, run by plain pytest in a subprocess)."""
from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from freebody.adapters.base import engine_names, is_available
from freebody.reference_impl.rotations import quat_from_rotvec, quat_multiply
from freebody.testing import I_FULL, assert_same_rotation, full_inertia, general_problem

# An angle well above the round-off of geodesic_angle (1e-16) and well below the offset put in.
ATOL = 1e-9  # rad
OFFSET = 1e-3  # rad: the rotation put on one sample
SUBPROCESS_TIMEOUT_S = 300


def _trajectory(n: int = 6) -> np.ndarray:
    return np.array([quat_from_rotvec(np.array([0.3 * k, -0.2, 0.5])) for k in range(n)])


def test_same_rotation_accepts_q_and_minus_q_and_broadcasts():
    q = _trajectory()
    assert_same_rotation(q, -q, ATOL)
    assert_same_rotation(q[2], -q[2], ATOL)
    assert_same_rotation(np.tile(q[0], (4, 1)), q[0], ATOL)  # (n, 4) against one (4,)


def test_same_rotation_says_where_and_by_how_much():
    q = _trajectory()
    r = q.copy()
    r[4] = quat_multiply(q[4], quat_from_rotvec(np.array([0.0, OFFSET, 0.0])))  # turned by OFFSET
    r[5] = quat_multiply(q[5], quat_from_rotvec(np.array([2 * OFFSET, 0.0, 0.0])))
    with pytest.raises(AssertionError) as e:
        assert_same_rotation(q, r, ATOL, "engine vs map")
    msg = str(e.value)
    assert msg.startswith("engine vs map: rotations differ by 0.001 rad")
    assert "at sample 4" in msg and "2 of 6 samples over" in msg, msg
    assert "largest 0.002 rad at sample 5" in msg, msg
    with pytest.raises(AssertionError, match="atol 1e-09 rad"):
        assert_same_rotation(q[4], r[4], ATOL)
    assert_same_rotation(q, r, 3 * OFFSET)  # inclusive bound, above both offsets


def test_same_rotation_fails_on_non_finite():
    q = _trajectory()
    bad = q.copy()
    bad[1] = np.nan
    with pytest.raises(AssertionError, match="at sample 1"):
        assert_same_rotation(q, bad, np.inf)


def test_general_problem_is_general_and_overridable():
    pb = general_problem()
    assert np.count_nonzero(pb.body.I_body - np.diag(np.diag(pb.body.I_body))) == 6  # full tensor
    np.testing.assert_allclose(np.linalg.eigvalsh(I_FULL), [1.0, 2.0, 3.0], rtol=1e-14)
    init = pb.initial
    for a in (init.position, init.linear_velocity, init.angular_velocity, init.quaternion_wxyz[1:],
              pb.gravity[2:]):
        assert np.all(a != 0.0), a
    assert pb.duration == 1.0 and pb.duration_steps is None
    other = general_problem(steps=7, mass=3.0, I_body=full_inertia((2.0, 2.0, 5.0)), w=(0, 0, 1))
    assert other.steps(0.01) == 7 and other.body.mass == 3.0 and other.duration is None
    assert np.array_equal(other.initial.angular_velocity, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(np.linalg.eigvalsh(other.body.I_body), [2.0, 2.0, 5.0], rtol=1e-14)


def _pytest_file(tmp_path, body: str) -> subprocess.CompletedProcess:
    (tmp_path / "test_user.py").write_text(textwrap.dedent(body))
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider",
                           "-o", "addopts=", "test_user.py"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=SUBPROCESS_TIMEOUT_S)


def test_make_adapter_builds_and_closes_at_teardown(tmp_path):
    """Imported into a user's test module, the fixture builds adapters (by name or class, the
    first offered precision by default) and closes each after the test."""
    proc = _pytest_file(tmp_path, """
        from freebody.adapters.reference import ReferenceAdapter
        from freebody.testing import general_problem, make_adapter

        CLOSED = []
        ReferenceAdapter.close = lambda self: CLOSED.append(self)
        INTEGRATOR = ReferenceAdapter.offered_integrators()[0]

        def test_build(make_adapter):
            a = make_adapter("reference", general_problem(), 0.01, INTEGRATOR)
            b = make_adapter(ReferenceAdapter, general_problem(), 0.02, INTEGRATOR, "float64")
            assert (a.dt, a.precision, b.dt) == (0.01, ReferenceAdapter.precisions[0], 0.02)
            assert CLOSED == []

        def test_closed_after_the_test():
            assert len(CLOSED) == 2
    """)
    assert proc.returncode == 0 and "2 passed" in proc.stdout, proc.stdout[-2000:]


def test_importing_the_helpers_does_not_import_pytest():
    code = ("import sys; import freebody.testing as t; t.assert_same_rotation; t.general_problem; "
            "t.assert_no_regression; assert 'pytest' not in sys.modules, 'pytest imported'")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=SUBPROCESS_TIMEOUT_S)
    assert proc.returncode == 0, proc.stderr


def test_a_subclass_without_engine_is_a_collection_error(tmp_path):
    proc = _pytest_file(tmp_path, """
        from freebody.testing import AdapterConformance

        class TestForgot(AdapterConformance):
            pass
    """)
    assert proc.returncode != 0 and "set engine" in proc.stdout, proc.stdout[-2000:]


def test_a_missing_engine_is_a_visible_skip_with_its_install_hint(tmp_path):
    missing = [name for name in engine_names() if not is_available(name)]
    if not missing:
        pytest.skip("every registered engine is installed here: no missing one to skip")
    proc = _pytest_file(tmp_path, f"""
        from freebody.testing import AdapterConformance

        class TestMissing(AdapterConformance):
            engine = {missing[0]!r}
    """)
    assert proc.returncode == 0, proc.stdout[-2000:]
    assert "13 skipped" in proc.stdout and f"{missing[0]} not installed (" in proc.stdout, proc.stdout
