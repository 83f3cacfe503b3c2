"""envs/vector.py: the batched vector environment (work in progress, see its docstring)."""
import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("pybullet")

import envs  # noqa: E402, F401


def test_one_robot_equals_the_single_environment_bit_for_bit():
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, size=(40, 1, 2)).astype(np.float32)
    venv = gym.make_vec("SphereBotWaypoints-v1", num_envs=1, vectorization_mode="vector_entry_point", estimator="ekf")
    obs, _ = venv.reset(seed=20)
    got = [obs[0]] + [venv.step(a)[0][0] for a in acts]
    venv.close()
    env = gym.make("SphereBotWaypoints-v1", estimator="ekf")
    obs, _ = env.reset(seed=20)
    want = [obs] + [env.step(a[0])[0] for a in acts]
    env.close()
    np.testing.assert_array_equal(np.array(got), np.array(want))


@pytest.mark.parametrize("n", [0, -1, 1.5, True])
def test_num_envs_must_be_a_positive_integer(n):
    from envs.vector import make_track_vec
    with pytest.raises(ValueError, match="num_envs"):
        make_track_vec(n)
