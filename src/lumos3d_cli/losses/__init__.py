"""Training losses: reconstruction, distillation, the Lumos loss, ground-truth supervision."""
