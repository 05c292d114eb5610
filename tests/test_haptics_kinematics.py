"""Falcon kinematics against the check values in the notes, a numerical derivative and itself."""
import math
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tearcloth.haptics.device import KinematicsError
from tearcloth.haptics import falcon_kinematics as fk

# /work/shared/notes/haptics.md, section 6 (degrees; encoder unrounded).
TABLE = [
    ((0.0, 0.0, 0.11), [16.18796] * 3, [131.73021] * 3, [91.06772] * 3, [-516.32] * 3),
    ((0.0, 0.0, 0.13), [31.49438] * 3, [127.87489] * 3, [91.06772] * 3, [-96.22] * 3),
    ((0.0, 0.0, 0.15), [47.24327] * 3, [122.03933] * 3, [91.06772] * 3, [336.03] * 3),
    (
        (0.02, 0.0, 0.12),
        [29.46540, 12.67232, 34.12954],
        [132.5242, 121.2341, 135.9919],
        [101.9529, 88.1738, 83.1461],
        [-151.90, -612.81, -23.89],
    ),
]


def _decimals(values):
    return max(len(f"{v:.5f}".rstrip("0").split(".")[1]) for v in values)


@pytest.mark.parametrize("p, t1, t2, t3, enc", TABLE)
def test_ik_matches_check_table(p, t1, t2, t3, enc):
    ang = np.degrees(fk.leg_angles(p))
    # The table is rounded: 5 decimals where given (tolerance 1e-4 deg), else to its last digit.
    for col, ref in ((0, t1), (1, t2), (2, t3)):
        tol = max(1e-4, 0.51 * 10.0 ** -_decimals(ref))
        np.testing.assert_allclose(ang[:, col], ref, atol=tol)
    np.testing.assert_allclose(fk.angle_to_encoder(np.radians(ang[:, 0])), enc, atol=0.006)
    # The vectorised path agrees with the single-point one.
    np.testing.assert_allclose(fk.inverse_kinematics(np.array([p]))[0], fk.leg_angles(p), atol=1e-12)


def test_vectorised_ik_marks_unreachable_with_nan_and_scalar_raises():
    out = fk.inverse_kinematics(np.array([[0.0, 0.06, 0.175], [0.0, 0.0, 0.13]]))
    assert np.isnan(out[0]).any() and np.isfinite(out[1]).all()
    with pytest.raises(KinematicsError, match="reach"):
        fk.leg_angles((0.0, 0.06, 0.175))


@pytest.mark.parametrize("p", [row[0] for row in TABLE])
def test_fk_recovers_table_positions_from_exact_encoders(p):
    enc = fk.angle_to_encoder(fk.actuator_angles(p))  # unrounded
    q = fk.forward_kinematics(fk.encoder_to_angle(enc))  # cold start from the centre
    assert np.linalg.norm(q - np.array(p)) < 1e-6


points = st.tuples(
    st.floats(-0.035, 0.035), st.floats(-0.035, 0.035), st.floats(0.095, 0.165)
)


@settings(max_examples=150, deadline=None)
@given(points, points)
def test_fk_recovers_position_to_a_micrometre(p, start):
    enc = fk.angle_to_encoder(fk.actuator_angles(p))
    q = fk.forward_kinematics(fk.encoder_to_angle(enc), guess=start)
    assert np.linalg.norm(q - np.array(p)) < 1e-6


@settings(max_examples=100, deadline=None)
@given(points)
def test_jacobian_matches_numerical_derivative(p):
    p = np.array(p)
    h = 1e-7
    num = np.column_stack(
        [(fk.actuator_angles(p + h * e) - fk.actuator_angles(p - h * e)) / (2 * h) for e in np.eye(3)]
    )
    jac = fk.jacobian(p)
    assert np.max(np.abs(jac - num)) < 1e-5 * max(1.0, np.max(np.abs(num)))


def test_corrected_jz_differs_from_the_legacy_formula():
    # The legacy sin²θ2 row is measurably wrong where θ3 is far from 90° (here 102°, 83°).
    p = (0.02, 0.0, 0.12)
    ang = fk.leg_angles(p)
    h = 1e-7
    num_z = (fk.actuator_angles((0.02, 0.0, 0.12 + h)) - fk.actuator_angles((0.02, 0.0, 0.12 - h))) / (2 * h)
    den = -fk.A * np.sin(ang[:, 2]) * np.sin(ang[:, 0] - ang[:, 1])
    legacy = np.sin(ang[:, 1]) ** 2 / den
    assert np.max(np.abs(fk.jacobian(p)[:, 2] - num_z)) < 1e-5
    assert np.max(np.abs(legacy - num_z)) > 1e-2


def test_torques_match_check_values():
    jac = fk.jacobian((0.0, 0.0, 0.13))
    np.testing.assert_allclose(fk.force_to_torque(jac, [0, 0, 1.0]), [0.025180] * 3, atol=1e-6)
    np.testing.assert_allclose(fk.force_to_torque(jac, [1.0, 0, 0]), [0.018640, -0.062994, 0.044354], atol=1e-6)
    # The stateful fast path gives the same torques.
    k = fk.FalconKinematics()
    k.update(tuple(fk.angle_to_encoder(fk.actuator_angles((0.0, 0.0, 0.13)))))
    np.testing.assert_allclose(k.torques_for_force((1.0, 0.0, 0.0)), [0.018640, -0.062994, 0.044354], atol=1e-6)


def test_effort_is_minus_10000_tau_truncated_then_limited():
    assert fk.torque_to_effort((0.025180, -0.00001, 0.01239)) == (-251, 0, -123)
    assert fk.torque_to_effort((1.0, 0.0, -0.2), clamp=4096, preserve_direction=False) == (-4096, 0, 2000)
    # Direction-preserving limit scales the whole vector: ratios survive.
    e = fk.torque_to_effort((1.0, 0.0, -0.2), clamp=4096)
    assert e[0] == -4096 and e[2] == int(4096 * 0.2)
    with pytest.raises(ValueError):
        fk.torque_to_effort((0, 0, 0), clamp=40000)


@settings(max_examples=300, deadline=None)
@given(
    st.tuples(*[st.floats(-1e4, 1e4)] * 3),
    points,
    st.integers(1, 32767),
    st.booleans(),
)
def test_efforts_never_exceed_the_clamp(force, p, clamp, preserve):
    k = fk.FalconKinematics(effort_clamp=clamp, preserve_direction=preserve)
    k.update(tuple(fk.angle_to_encoder(fk.actuator_angles(p))))
    e = k.efforts_for_force(force)
    assert all(isinstance(v, int) and -clamp <= v <= clamp for v in e)


def test_encoder_angle_conversions_invert():
    counts = np.arange(-2000, 2000, 7)
    np.testing.assert_allclose(fk.angle_to_encoder(fk.encoder_to_angle(counts)), counts, atol=1e-9)
    assert fk.encoder_to_angle(0) == pytest.approx(math.radians(35.0))


def test_warm_started_fk_tracks_a_trajectory_and_is_fast():
    k = fk.FalconKinematics()
    path = [(0.02 * math.sin(i / 90), 0.015 * math.cos(i / 70), 0.13 + 0.025 * math.sin(i / 50)) for i in range(1000)]
    encs = [tuple(int(round(v)) for v in fk.angle_to_encoder(fk.actuator_angles(q))) for q in path]
    t0 = time.perf_counter()
    for e, q in zip(encs, path):
        pos = k.update(e)
        k.efforts_for_force((1.0, -2.0, 0.5))
        # Rounded encoders: one count is ~50 µm at the grip.
        assert np.linalg.norm(np.array(pos) - np.array(q)) < 2e-4
    per_call = (time.perf_counter() - t0) / len(encs)
    assert per_call < 1e-3  # generous (target ~40 µs); catches an accidental O(n) or numpy-heavy path
