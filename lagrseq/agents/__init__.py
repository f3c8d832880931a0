"""Learning agents. They know only arrays, actions and rewards: no tasks, envs, LLMs or logs.

- :mod:`lagrseq.agents.tabular`: tabular Q-learning and epsilon-greedy selection.
- :mod:`lagrseq.agents.schedules`: exploration schedules (per episode or per step).
- :mod:`lagrseq.agents.replay`: the replay buffer (numpy).
- :mod:`lagrseq.agents.dqn`: the deep Q-network (torch, imported only when a DQN is built).
- :mod:`lagrseq.agents.batched`: the DQN's seed-batched backend (the networks of many trials
  stacked, trained in one call).
- :mod:`lagrseq.agents.lockstep`: several trials in one process, their updates batched.
"""
