"""The task world: signals, schedules, dynamics, controlled elements and recordings."""
