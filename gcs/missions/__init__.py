"""Mission files and QGroundControl plans: read, checked, and flown as plans."""
