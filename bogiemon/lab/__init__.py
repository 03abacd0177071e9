"""The offline lab: the detection study, the robustness evaluation and the fitting of the shipped
models. It depends on the product (daemon/, simulator/, detection/); the product never loads it:
only the `study` and `evaluate` commands import it, when they run."""
