import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio.motion.trapezoid import move_time, position_at

finite = st.floats(-400, 400, allow_nan=False)
speed = st.floats(0.1, 500, allow_nan=False)


@settings(derandomize=True, max_examples=300)
@given(t=st.floats(-1, 50), start=finite, target=finite, v=speed, a=speed)
def test_scalar_and_array_paths_agree(t, start, target, v, a):
    scalar = position_at(t, start, target, v, a)
    array = position_at(np.array([t]), np.array([start]), np.array([target]), v, a)[0]
    assert isinstance(scalar, float)
    assert abs(scalar - array) <= 1e-9 * max(1.0, abs(start), abs(target))
    assert abs(move_time(target - start, v, a) - move_time(np.array([target - start]), v, a)[0]) < 1e-9


def test_profile_shape():
    # 90° at 60°/s and 120°/s²: 0.5 s accelerating (15°), 1 s cruising (60°), 0.5 s braking (15°)
    assert move_time(90.0, 60.0, 120.0) == 2.0
    np.testing.assert_allclose(position_at(np.array([0.0, 0.5, 1.0, 1.5, 2.0, 9.0]), 0.0, 90.0, 60.0, 120.0),
                               [0.0, 15.0, 45.0, 75.0, 90.0, 90.0])
    # too short to reach cruise speed: a triangle, 2·sqrt(d/a)
    assert move_time(-3.0, 60.0, 120.0) == 2.0 * np.sqrt(3.0 / 120.0)
    assert position_at(1.0, 10.0, 7.0, 60.0, 120.0) == 7.0


@settings(derandomize=True, max_examples=200)
@given(d1=st.floats(0, 300), d2=st.floats(0, 300), v=speed, a=speed)
def test_move_time_is_subadditive_so_it_is_a_metric(d1, d2, v, a):
    """The motion lower bound relies on the triangle inequality of move time."""
    assert move_time(d1 + d2, v, a) <= move_time(d1, v, a) + move_time(d2, v, a) + 1e-9
