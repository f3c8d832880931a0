"""Running trials: building a trial's parts from the configuration (wiring), the runner and its executors, recording answers, the suite."""
