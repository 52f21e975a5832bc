"""Training: data generation from catalogue objects and the CNN's training protocol."""
