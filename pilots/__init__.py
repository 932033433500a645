"""manualcontrol.pilots."""
