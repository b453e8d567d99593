"""render_mode="rgb_array" on the Drake envs (assembly/envs/rendering.py) and the registered
episode lengths (spec.max_episode_steps, gymnasium's TimeLimit): docs/envs.md, "Rendering and
episode length"."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import assembly.envs  # noqa: F401  (registers the goflow/ ids)
from assembly.envs import VECTOR_ENVS
from goflow_common.errors import InputError

# (id, kwargs) of every env that renders; GearInsertion in both variants.
RENDERED = [
    ("goflow/Cartpole-v0", {}),
    ("goflow/Quadrotor-v0", {}),
    ("goflow/Ant-v0", {}),
    ("goflow/Anymal-v0", {}),
    ("goflow/Hopper-v0", {}),
    ("goflow/Walker2d-v0", {}),
    ("goflow/HalfCheetah-v0", {}),
    ("goflow/Humanoid-v0", {}),
    ("goflow/GearInsertion-v0", {"variant": "fast"}),
    ("goflow/GearInsertion-v0", {"variant": "panda"}),
]
IDS = sorted(k for k in gymnasium.registry if k.startswith("goflow/"))
STEPS = 8  # control steps per rendering test


def _label(case) -> str:
    env_id, kwargs = case
    return env_id.split("/")[1] + "".join(f"-{v}" for v in kwargs.values())


def _state(env) -> np.ndarray:
    """Everything the physics holds for `env` (unwrapped): the plant state, or for GearInsertion
    the tool pose and the gear's insertion error."""
    if hasattr(env, "plant_state"):
        return np.asarray(env.plant_state)
    if hasattr(env, "state"):
        return env.state()
    return np.concatenate([env.tool_pose(), env.insertion_error()])


@pytest.mark.parametrize("case", RENDERED, ids=_label)
def test_render_gives_changing_frames_and_leaves_the_physics_alone(case) -> None:
    """render() is an (H, W, 3) uint8 picture (not one flat colour) that changes as the episode
    runs; an env rendering every step steps bit for bit like one made without render_mode."""
    env_id, kwargs = case
    plain = gymnasium.make(env_id, **kwargs)
    drawn = gymnasium.make(env_id, render_mode="rgb_array", **kwargs)
    assert drawn.unwrapped.metadata["render_fps"] == pytest.approx(1.0 / drawn.unwrapped.control_dt)
    assert drawn.unwrapped.metadata["render_modes"] == ["rgb_array"]
    obs_p, _ = plain.reset(seed=3)
    obs_d, _ = drawn.reset(seed=3)
    first = drawn.render()
    assert first.shape == (480, 480, 3) and first.dtype == np.uint8
    assert len(np.unique(first.reshape(-1, 3), axis=0)) > 20, "the frame is (nearly) one colour"
    rng = np.random.default_rng(0)
    for _ in range(STEPS):
        action = rng.uniform(-1.0, 1.0, size=plain.action_space.shape).astype(np.float32)
        out_p, out_d = plain.step(action), drawn.step(action)
        frame = drawn.render()
        assert np.array_equal(out_p[0], out_d[0]) and out_p[1:4] == out_d[1:4]
        assert np.array_equal(_state(plain.unwrapped), _state(drawn.unwrapped))
        if out_p[2] or out_p[3]:
            break
    assert np.array_equal(obs_p, obs_d)
    assert np.abs(frame.astype(np.int64) - first).mean() > 0.05, "the picture did not change over the steps"


def test_render_without_a_render_mode_warns_and_returns_none() -> None:
    env = gymnasium.make("goflow/Cartpole-v0")
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode None"):
        assert env.unwrapped.render() is None


@pytest.mark.parametrize("env_id", [e for e in IDS if e != "goflow/Toy2D-v0"])
def test_an_unknown_render_mode_is_refused_naming_it(env_id: str) -> None:
    cls = gymnasium.envs.registration.load_env_creator(gymnasium.spec(env_id).entry_point)
    with pytest.raises(
        ValueError, match=r"render_mode='human' is not supported; expected None or one of \['rgb_array'\]"
    ):
        cls(render_mode="human")


def test_toy2d_does_not_render() -> None:
    from assembly.envs.toy2d import Toy2DEnv

    assert Toy2DEnv.metadata["render_modes"] == []
    with pytest.raises(ValueError, match=r"render_mode='rgb_array' is not supported; expected None \(Toy2DEnv"):
        Toy2DEnv(render_mode="rgb_array")
    assert Toy2DEnv(render_mode=None).render_mode is None


@pytest.mark.parametrize("env_id", sorted(VECTOR_ENVS))
def test_batched_envs_refuse_render_mode(env_id: str) -> None:
    with pytest.raises(InputError, match="render_mode='rgb_array' is not supported; expected None"):
        gymnasium.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", render_mode="rgb_array")


def test_gymnasium_checkers_accept_the_render() -> None:
    """check_env's render checks (it also makes the env again in each declared render mode) and
    RenderCollection (render_mode "rgb_array_list") pass."""
    env = gymnasium.make("goflow/Cartpole-v0", render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a checker's complaint is a warning
        check_env(env.unwrapped)
    frames_env = gymnasium.make("goflow/Cartpole-v0", render_mode="rgb_array_list")
    frames_env.reset(seed=0)
    for _ in range(3):
        frames_env.step(frames_env.action_space.sample())
    frames = frames_env.render()
    assert len(frames) == 4 and all(f.shape == (480, 480, 3) for f in frames)


def test_record_video(tmp_path) -> None:
    pytest.importorskip("moviepy")
    env = gymnasium.wrappers.RecordVideo(
        gymnasium.make("goflow/Cartpole-v0", render_mode="rgb_array"), str(tmp_path), episode_trigger=lambda e: True
    )
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        done = terminated or truncated
    env.close()
    assert list(tmp_path.glob("*.mp4"))


# -- episode length ------------------------------------------------------------------------------


@pytest.mark.parametrize("env_id", IDS)
def test_spec_max_episode_steps_is_the_envs_own_episode_length(env_id: str) -> None:
    env = gymnasium.make(env_id)
    assert gymnasium.spec(env_id).max_episode_steps == env.unwrapped.max_episode_steps
    if env.unwrapped.max_episode_steps is not None:
        assert env.spec.max_episode_steps == env.unwrapped.max_episode_steps


def _truncations(env, steps: int) -> list[tuple[bool, bool]]:
    env.reset(seed=0)
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    return [env.step(zero)[2:4] for _ in range(steps)]


@pytest.mark.parametrize(
    "env_id, kwargs",
    [("goflow/Cartpole-v0", {}), ("goflow/Quadrotor-v0", {}), ("goflow/GearInsertion-v0", {"variant": "fast"})],
)
def test_an_episode_through_gymnasium_make_is_truncated_once_at_the_spec_length(env_id: str, kwargs) -> None:
    """The env's own time limit and gymnasium's TimeLimit end the episode on the same step."""
    env = gymnasium.make(env_id, **kwargs)
    n = gymnasium.spec(env_id).max_episode_steps
    flags = _truncations(env, n)
    assert flags == [(False, False)] * (n - 1) + [(False, True)]
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(np.zeros(env.action_space.shape, dtype=np.float32))


def test_a_changed_t_max_through_gymnasium_make() -> None:
    """A shorter t_max ends the episode first (TimeLimit never fires); a longer one needs
    max_episode_steps=-1 (or its step count) so that TimeLimit does not cut it at the spec's 120."""
    short = gymnasium.make("goflow/Cartpole-v0", t_max=0.5)
    assert _truncations(short, 30) == [(False, False)] * 29 + [(False, True)]
    long = gymnasium.make("goflow/Cartpole-v0", t_max=2.5, max_episode_steps=-1)
    assert long.unwrapped.max_episode_steps == 150
    assert _truncations(long, 150) == [(False, False)] * 149 + [(False, True)]


def test_batched_episode_length_follows_the_single_env() -> None:
    """make_vec passes the spec's max_episode_steps: the copies end at the earlier of it and t_max,
    as a single env made by gymnasium.make does; -1 leaves t_max alone."""

    def steps(**kwargs) -> int:
        vec = gymnasium.make_vec("goflow/Cartpole-v0", num_envs=1, vectorization_mode="vector_entry_point", **kwargs)
        return vec.unwrapped.max_episode_steps

    assert steps() == 120
    assert steps(t_max=0.5) == 30
    assert steps(max_episode_steps=50) == 50
    assert steps(t_max=2.5) == 120
    assert steps(t_max=2.5, max_episode_steps=-1) == 150
    with pytest.raises(InputError, match="max_episode_steps = 0"):
        steps(max_episode_steps=0)


@pytest.mark.parametrize("vectorization", ["sync", "batched"])
def test_training_envs_keep_a_longer_t_max(vectorization: str) -> None:
    """learning.experiment.make_vector_env makes the envs with max_episode_steps=-1: an env_kwargs
    t_max longer than the spec's default is honoured in both vectorizations."""
    from learning.experiment import TrainConfig, make_vector_env

    vec = make_vector_env(
        TrainConfig(env="goflow/Cartpole-v0", env_kwargs={"t_max": 2.5}, vectorization=vectorization), 2
    )
    vec.reset(seed=0)
    zero = np.zeros((2, 1), dtype=np.float32)
    ends = [bool(np.any(vec.step(zero)[3])) for _ in range(150)]
    assert ends == [False] * 149 + [True]
