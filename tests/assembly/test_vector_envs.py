"""Many environments across processes, seeded: reproducible and independent."""

import gymnasium
import numpy as np

import assembly  # noqa: F401  (registers the ids)


def _first_steps(env_id: str, seed: int, **kwargs):
    vec = gymnasium.vector.AsyncVectorEnv([lambda: gymnasium.make(env_id, **kwargs) for _ in range(2)])
    try:
        obs, info = vec.reset(seed=seed)
        vec.action_space.seed(seed)
        obs2, reward, terminated, truncated, info2 = vec.step(vec.action_space.sample())
        return obs, info["xi"], obs2, reward
    finally:
        vec.close()


def test_gear_insertion_vectorized_is_seeded():
    a = _first_steps("goflow/GearInsertion-v0", 7, variant="fast")
    b = _first_steps("goflow/GearInsertion-v0", 7, variant="fast")
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    xi = a[1]
    assert xi.shape == (2, 3) and not np.allclose(xi[0], xi[1])  # sub-envs draw their own xi


def test_toy2d_vectorized_different_seeds_differ():
    a = _first_steps("goflow/Toy2D-v0", 1)
    b = _first_steps("goflow/Toy2D-v0", 2)
    assert not np.allclose(a[1], b[1])
