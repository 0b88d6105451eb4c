"""The benchmark and stress harness, beside the simulator and never imported by it.

- `harness`: the sweep's scenes, probes, accuracy and timing runs, run time against error, scaling;
- `report`: markdown, plots and README.md's results block, from the harness's JSON;
- `runner`: what the harness asks of every engine, and `StepFailed`;
- `peers`: MuJoCo and pinocchio on the builder's scene (the reference and the peers);
- `stress`: the stress suite;
- `cli`: the `warpimpulse bench` and `warpimpulse stress` commands.

Only `warpimpulse.cli` reaches in here, from inside its command dispatch (tests/test_layout.py checks it).
"""
