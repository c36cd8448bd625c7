"""The per-map-run set-up a sweep's identification pays 135 times a body (27 candidate maps x the
run and its four perturbed starts), made cheaper without changing a bit."""
import dataclasses

import numpy as np

from freebody.reference_impl.compiled import mat, vec
from freebody.reference_impl.problem import Body
from freebody.reference_impl.rotations import matrix_from_quat


def test_one_quaternion_matrix_is_the_batched_one_bit_for_bit():
    rng = np.random.default_rng(7)
    q = rng.normal(size=(500, 4)) * rng.uniform(0.5, 2.0, size=(500, 1))  # not unit: normalised there
    one_by_one = np.array([matrix_from_quat(row) for row in q])
    assert one_by_one.shape == (500, 3, 3)
    assert np.array_equal(one_by_one.view(np.uint64), matrix_from_quat(q).view(np.uint64))


def test_body_inverse_once_and_a_fresh_copy_each_call():
    body = Body(2.0, np.array([[1.0, 0.1, 0.0], [0.1, 2.0, 0.2], [0.0, 0.2, 3.0]]))
    first = body.I_body_inv
    assert np.array_equal(first, np.linalg.inv(body.I_body))
    first[0, 0] = 99.0  # a caller writing to it changes nothing of the body's
    assert np.array_equal(body.I_body_inv, np.linalg.inv(body.I_body))
    other = dataclasses.replace(body, I_body=2.0 * np.eye(3))  # a perturbed start: its own inverse
    assert np.array_equal(other.I_body_inv, 0.5 * np.eye(3))


def test_vec_and_mat_give_python_floats():
    a = np.arange(9.0).reshape(3, 3) / 7.0
    assert mat(a) == tuple(tuple(float(v) for v in row) for row in a)
    assert vec(np.float32([0.1, 2.0, 3.0])) == tuple(float(v) for v in np.float32([0.1, 2.0, 3.0]))
    assert all(type(v) is float for v in vec(a[0]))
