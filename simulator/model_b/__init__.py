"""Model B: a second Y25 wagon model, formulated independently of model A (docs/simulator-b.md)."""
