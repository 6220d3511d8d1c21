"""docs/extending.md, checked: the env and algorithm catalogues, and a new env and a new algorithm added exactly as the
doc says (a toy 1-D point env with scripted experts, a random policy), registered with one line each (here through
monkeypatch, so the registries are restored), scripted demos written by ``harness data scripted`` into a data directory
of their own, then the real ``harness run`` on them for a tiny budget."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import pytest

from algorithms.api import AlgoConfig, Algorithm, setting
from algorithms.common import load_rng_states, member_rngs, rng_states
from algorithms.core.nets import Stream
from harness.cli import main
from harness.data import load_demos
from harness.envs import ENVS, EVAL_HORIZONS, GYM_IDS, EarlEnv, EnvInfo, EnvSpec, get_spec, make_env, register_gym
from harness.labels import algo_label, env_label
from harness.registry import ALGORITHMS
from harness.results import load, read_status

# -------------------------------------------------------------------------- the catalogues


def test_every_registered_algorithm_has_its_own_label():
    labels = {name: cls.__dict__.get("label") for name, cls in ALGORITHMS.items()}
    assert all(isinstance(v, str) and v.strip() for v in labels.values()), labels  # set on the class itself
    assert len(set(labels.values())) == len(labels), labels
    assert all(algo_label(name) == label for name, label in labels.items())


def test_every_registered_env_is_one_record():
    for name, info in ENVS.items():
        assert isinstance(info, EnvInfo) and info.name == name and info.label.strip()
        assert info.default_steps > 0 and info.bench_steps > 0
        assert GYM_IDS[name] == info.spec.gym_id and EVAL_HORIZONS[name] == info.spec.eval_horizon
        assert get_spec(name) is info.spec and env_label(name) == info.label
        assert (info.experts is None) == (info.scripted_demos == (0, 0))
    assert len({i.label for i in ENVS.values()}) == len({i.spec.gym_id for i in ENVS.values()}) == len(ENVS)


def test_the_catalogue_does_not_import_the_simulators():
    """Importing the env registry (as every command does) must not pay for Meta-World."""
    import subprocess
    import sys

    code = "import sys, harness.envs, harness.analysis; print('metaworld' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "False"


# -------------------------------------------------------------------------- a new env: harness/envs/point.py


def point_expert(obs: np.ndarray) -> np.ndarray:
    """Step towards the goal written in the observation (both directions)."""
    return np.clip((obs[1:2] - obs[0:1]) / POINT_STEP, -1.0, 1.0).astype(np.float32)


POINT_STEP = 0.1
POINT_SPEC = EnvSpec(
    name="toy_point", gym_id="toy/Point-v0", state_dim=1, act_dim=1, success_idx=(0,), success_threshold=0.05,
    train_horizon=150, eval_horizon=30, initial_states=np.array([[0.0]]), goal_states=np.array([[0.5], [-0.5]]),
)


class PointEnv(EarlEnv):
    """A point on [-1, 1] moved by ``0.1 * a``; observation ``[x, goal]``."""

    spec_ = POINT_SPEC

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        options = options or {}
        state = np.asarray(options.get("state", [0.0, np.nan]), dtype=np.float64)
        self._x = float(state[0])
        goal = options.get("goal", state[1:] if "state" in options else self.sample_goal())
        self._goal = np.asarray(goal, dtype=np.float64).reshape(1)
        obs = self._obs()
        return obs, {"success": bool(self.spec_.is_success(obs))}

    def step(self, action):
        self._x = float(np.clip(self._x + POINT_STEP * np.clip(action[0], -1.0, 1.0), -1.0, 1.0))
        obs = self._obs()
        success = bool(self.spec_.is_success(obs))
        return obs, float(success), False, False, {"success": success}

    def _obs(self) -> np.ndarray:
        return np.array([self._x, self._goal[0]], dtype=np.float32)

    def get_sim_state(self):
        return {"x": self._x, "goal": self._goal.copy(), "rng": self._rng_state()}

    def set_sim_state(self, state):
        self._x, self._goal = state["x"], np.array(state["goal"])
        self._set_rng_state(state["rng"])


POINT = EnvInfo(spec=POINT_SPEC, label="Toy Point", env_class=PointEnv, default_steps=10_000,
                experts=(point_expert, point_expert), scripted_demos=(3, 3))


# -------------------------------------------------------------------------- a new algorithm: algorithms/random_policy.py


@dataclass
class RandomPolicyConfig(AlgoConfig):
    scale: float = setting(1.0, "largest |action| of the uniform training actions", gt=0.0, le=1.0)


class RandomPolicy(Algorithm):
    """Uniform random actions in training, the zero action in evaluation; learns nothing."""

    label = "random policy"
    Config = RandomPolicyConfig

    def __init__(self, task, demos, cfg, seeds, device):
        super().__init__(task, demos, cfg, seeds, device)
        self.rngs = member_rngs(self.seeds, Stream.GC_WARMUP)

    def on_reset(self, obs, mask):
        pass

    def act(self, obs):
        s = self.cfg.scale
        return np.stack([r.uniform(-s, s, self.task.act_dim) for r in self.rngs]).astype(np.float32)

    def observe(self, next_obs, hard_reset):
        return np.zeros(self.E, dtype=bool)

    def eval_act(self, obs):
        return np.zeros((len(obs), self.task.act_dim), dtype=np.float32)

    def state_dict(self):
        return {"rngs": rng_states(self.rngs)}

    def load_state_dict(self, state):
        load_rng_states(self.rngs, state["rngs"])


# -------------------------------------------------------------------------- a variant: algorithms/naive_shaped.py


from algorithms.naive import Naive  # noqa: E402


class NaiveShaped(Naive):
    """Naive RL on 1[success] minus the distance to the goal (on the env's success coordinates)."""

    label = "naive RL, shaped"

    def reward(self, batch):  # batch["next_obs"]: (E, B, obs_dim), each row [state, goal]
        return batch["reward"] - self.task.goal_distance(batch["next_obs"])


# -------------------------------------------------------------------------- registering them, and running


@pytest.fixture
def registered(monkeypatch):
    """The two registration lines of docs/extending.md (undone after the test), and the gym id."""
    monkeypatch.setitem(ENVS, "toy_point", POINT)
    monkeypatch.setitem(ALGORITHMS, "random_policy", RandomPolicy)
    register_gym()
    yield
    gym.registry.pop(POINT.spec.gym_id, None)


def test_a_new_env_behaves_like_the_earl_envs(registered):
    env = gym.make("toy/Point-v0")
    obs, info = env.reset(seed=0)
    assert obs.shape == (2,) and obs[0] == 0.0 and not info["success"]
    for t in range(env.spec.max_episode_steps):
        obs, r, term, _, info = env.step(point_expert(obs))
        assert not term
        if info["success"]:
            break
    assert info["success"] and r == 1.0 and t == 4
    assert env.spec.max_episode_steps == POINT.spec.eval_horizon and env_label("toy_point") == "Toy Point"
    assert algo_label("random_policy") == "random policy"


def test_a_new_env_and_algorithm_run_the_real_protocol(registered, tmp_path, capsys):
    data, results = tmp_path / "data", tmp_path / "results"
    assert main(["data", "scripted", "env=toy_point", f"out={data}"]) == 0
    fwd, rev = load_demos("toy_point", "forward", data_dir=data), load_demos("toy_point", "reverse", data_dir=data)
    assert fwd.source == rev.source == "scripted" and fwd.terminals.sum() == rev.terminals.sum() == 3
    assert make_env("toy_point").spec_.is_success(rev.next_observations[rev.terminals]).all()

    args = ["--data-dir", str(data), "run", "algo=random_policy", "env=toy_point", "seeds=2", "steps=200",
            "eval_every=100", "checkpoint_every=100", "eval_episodes=2", "workers=1", f"results={results}"]
    assert main(args) == 0, capsys.readouterr().err
    df = load(results)
    d = df[df.metric == "deployed_success"]
    assert sorted(zip(d.seed, d.step)) == [(s, t) for s in (0, 1) for t in (0, 100, 200)]
    assert (d.value == 0.0).all()  # the zero action never moves the point to a goal
    assert set(df.env) == {"toy_point"} and set(df.algo) == {"random_policy"} and (df.demo_source == "scripted").all()
    for s in (0, 1):
        assert read_status(results / "adhoc" / "toy_point" / "random_policy" / f"seed={s}")["state"] == "done"


def test_without_demos_a_new_env_says_where_they_come_from(registered, tmp_path, capsys):
    assert main(["--data-dir", str(tmp_path), "run", "algo=random_policy", "env=toy_point", "steps=100",
                 f"results={tmp_path / 'r'}"]) == 2
    err = capsys.readouterr().err
    assert "harness data scripted env=toy_point" in err and len(err.strip().splitlines()) == 1


def test_a_variant_overrides_one_hook_and_runs(registered, monkeypatch, tmp_path, capsys):
    """docs/extending.md's variant: the shaped reward is what the agent learns from (hand-computed on a batch), and
    the real protocol runs it past its seed phase."""
    import torch

    calls = []

    class Counted(NaiveShaped):
        def reward(self, batch):
            calls.append(batch["reward"].shape)
            return super().reward(batch)

    monkeypatch.setitem(ALGORITHMS, "naive_shaped", Counted)
    data, results = tmp_path / "data", tmp_path / "results"
    assert main(["data", "scripted", "env=toy_point", f"out={data}"]) == 0
    args = ["--data-dir", str(data), "run", "algo=naive_shaped", "env=toy_point", "seed=0", "steps=200",
            "eval_every=100", "eval_episodes=1", "naive_shaped.seed_steps=50", "naive_shaped.batch_size=8",
            "workers=1", f"results={results}"]
    assert main(args) == 0, capsys.readouterr().err
    train = load(results, filename="train.parquet")
    assert set(train.algo) == {"naive_shaped"} and len(train)
    assert len(calls) == 150 and calls[0] == (1, 8)  # every update past the 50 seed steps, on its sampled batch
    spec = get_spec("toy_point")
    next_obs = torch.tensor([[[0.5, 1.0], [1.0, 1.0]]])  # [x, goal]: 0.5 away, and at the goal
    algo = NaiveShaped.__new__(NaiveShaped)
    algo.task = spec
    shaped = algo.reward({"reward": torch.tensor([[0.0, 1.0]]), "next_obs": next_obs})
    assert torch.allclose(shaped, torch.tensor([[-0.5, 1.0]]))
