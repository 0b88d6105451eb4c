"""The benchmark and stress harness, beside the simulator and never imported by it.

- `harness`: the sweep's scenes, probes, accuracy and timing runs, run time against error, scaling;
- `report`: markdown, plots and README.md's results block, from the harness's JSON;
- `peers`: MuJoCo and pinocchio on the builder's scene (the reference and the peers);
- `stress`: the stress suite (`warpimpulse stress`);
- `cli`: the `warpimpulse bench` command.

Only `warpimpulse.cli` reaches in here, from inside its `bench` and `stress` commands.
"""
