"""manualcontrol.estimators."""
