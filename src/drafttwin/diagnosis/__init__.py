"""Fault diagnosis on the twin's residuals: detection, localisation, severity."""
