"""Learning agents. They know only arrays, actions and rewards: no tasks, envs, LLMs or logs.

- :mod:`lagrseq.agents.tabular`: tabular Q-learning and epsilon-greedy selection.
- :mod:`lagrseq.agents.schedules`: exploration schedules.
"""
