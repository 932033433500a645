"""manualcontrol.agents."""
