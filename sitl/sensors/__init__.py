"""Sensor models with seeded noise: IMU, GPS, barometer, magnetometer."""
