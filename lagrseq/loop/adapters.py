"""What the loop asks of the primary agent, and the adapters that give it and the neural
secondary agent's (:class:`lagrseq.loop.policies.SecondaryAgent`; the tabular one,
:class:`lagrseq.loop.seq.TabularSecondary`, needs none).

The agents in ``agents/`` know only arrays, keys and gymnasium spaces; these adapters hold one and
translate the loop's :class:`Step` (observations, the env's ``info``) into what it needs: the
tabular agent's state key (the task's own state index where configured), the DQN's
observation vector. Composition throughout: an adapter holds its agent, it never subclasses it.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Any, NamedTuple, Protocol

import numpy as np

from lagrseq import seeding
from lagrseq.agents.tabular import TabularQ, epsilon_greedy
from lagrseq.config import DQNConfig, NeuralSecondaryConfig, TabularConfig
from lagrseq.seeding import Stream


class Step(NamedTuple):
    """One environment step as an agent learns from it. The logged ``Transition`` holds only the
    pattern; agents also need the observations and the env's ``info`` before and after."""

    observation: Any
    info: dict[str, Any]
    action: int
    reward: float
    next_observation: Any
    next_info: dict[str, Any]
    terminated: bool


class PrimaryAgent(Protocol):
    """The primary RL agent: acts on the task, learns from every step it is updated on."""

    def act(self, observation: Any, info: dict[str, Any], epsilon: float, rng: np.random.Generator) -> int: ...

    def learn(self, step: Step) -> None: ...


class TabularTask(Protocol):
    """What tabular Q-learning needs of a task: its action count."""

    n_actions: int


class TabularPrimary:
    """Tabular Q-learning on the task's patterns (any task with ``n_actions`` whose env gives
    ``info["action_mask"]``). ``state_key``: a pattern's Q-table row under the configured state
    index (the task's registered ``state_keys`` entry, looked up once per pattern); None: one
    row per exact pattern."""

    def __init__(self, section: TabularConfig, task: TabularTask, state_key: Callable[[Any], Hashable] | None = None) -> None:
        self.agent = TabularQ(task.n_actions, section.learning_rate, section.discount)
        self.invalid = section.invalid_actions
        self.pre_revert = section.bootstrap_from == "pre-revert"
        if state_key is not None:
            index = state_key
            keys: dict[Any, Hashable] = {}  # a trial visits a few dozen patterns, 10,000 times

            def key(pattern: Any) -> Hashable:
                found = keys.get(pattern)
                if found is None:
                    found = keys[pattern] = index(pattern)
                return found

            self.key: Callable[[Any], Hashable] = key
        else:
            self.key = tuple

    def act(self, observation: Any, info: dict[str, Any], epsilon: float, rng: np.random.Generator) -> int:
        key = self.key(info["pattern"])
        agent = self.agent  # TabularQ.act, its row looked up here (one call fewer a step)
        row = agent.table.get(key)
        return epsilon_greedy(agent.values(key) if row is None else row, epsilon, rng, info["action_mask"], self.invalid)

    def learn(self, step: Step) -> None:
        # The released cube code bootstraps from the wrong stack before its revert (value 0).
        following = step.next_info["pre_revert_pattern"] if self.pre_revert else step.next_info["pattern"]
        self.agent.update(
            self.key(step.info["pattern"]), step.action, step.reward, self.key(following), step.terminated
        )


# The primary and secondary networks each get their own part of the TORCH and REPLAY streams.
PRIMARY_PART, SECONDARY_PART = 0, 1


class DQNPrimary:
    """A DQN on the environment's observation vector (grid tasks; torch is imported here)."""

    def __init__(self, section: DQNConfig, env: Any, seed: int, trial: int) -> None:
        from lagrseq.agents.dqn import DQN

        space = env.observation_space
        normalise = section.normalise_observations
        self.agent = DQN(
            observation_size=int(space.shape[0]),
            n_actions=int(getattr(env.unwrapped, "agent_action_space", env.action_space).n),  # the actions at the cursor
            hidden_sizes=section.hidden_sizes,
            learning_rate=section.learning_rate,
            discount=section.discount,
            batch_size=section.batch_size,
            buffer_size=section.buffer_size,
            target_update_interval=section.target_update_interval,
            seed=seeding.integer_seed(seed, trial, Stream.TORCH, PRIMARY_PART),
            device=section.device,
            observation_low=space.low if normalise else None,
            observation_high=space.high if normalise else None,
            cpu_threads=section.cpu_threads,
        )
        self.replay_rng = seeding.generator(seed, trial, Stream.REPLAY, PRIMARY_PART)

    def act(self, observation: Any, info: dict[str, Any], epsilon: float, rng: np.random.Generator) -> int:
        return self.agent.act(observation, epsilon, rng)

    def learn(self, step: Step) -> None:
        # Bootstrap from the real next observation (the released code's can be stale, SPEC 7.15),
        # then one optimiser step per environment step.
        self.agent.remember(step.observation, step.action, step.reward, step.next_observation, step.terminated)
        self.agent.train_step(self.replay_rng)


class NeuralSeq:
    """The neural SEQ bandit on the flattened grid: Q2(s) = [skip, query], fitted to r2."""

    def __init__(self, section: NeuralSecondaryConfig, cells: int, seed: int, trial: int) -> None:
        from lagrseq.agents.dqn import DQN

        self.agent = DQN(
            observation_size=cells,
            n_actions=2,
            hidden_sizes=section.hidden_sizes,
            learning_rate=section.learning_rate,
            discount=0.0,  # a bandit: every decision ends
            batch_size=section.batch_size,
            buffer_size=section.buffer_size,
            target_update_interval=0,
            seed=seeding.integer_seed(seed, trial, Stream.TORCH, SECONDARY_PART),
            device=section.device,
        )
        self.replay_rng = seeding.generator(seed, trial, Stream.REPLAY, SECONDARY_PART)

    @staticmethod
    def _vector(pattern: Any) -> np.ndarray:
        return np.asarray(pattern, dtype=np.float32).ravel()

    def decide(self, pattern: Any, epsilon: float, rng: np.random.Generator) -> int:
        """epsilon-greedy over {0: skip, 1: query}; ties choose 0."""
        return self.agent.act(self._vector(pattern), epsilon, rng)

    def update(self, pattern: Any, decision: int, reward: float) -> None:
        vector = self._vector(pattern)
        self.agent.remember(vector, decision, reward, vector, True)
        self.agent.train_step(self.replay_rng)
