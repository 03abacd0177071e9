"""Model B: a second Y25 wagon model, formulated independently of model A (docs/simulator-b.md).

Selected per scenario (`Scenario(model="b")`); simulator/run.py dispatches model-B scenarios to
`run.run_group`. Modules: parameters (config/y25_wagon_b.toml), friction (Lenoir and bowl, LuGre
bristles), contact (Hertz and track), bodies (equations, reference step, rest, modes), track,
sensors (the MEMS chain), kernel (numba), run.
"""
