"""manualcontrol.bench."""
