"""Studies run by make targets (each writes under results/)."""
