"""What both the models and the engine are built on: sample screening, direction detection,
the voltage divider, the Compensator contract, the array protocol and the model registry."""
