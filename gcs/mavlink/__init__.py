"""The ground station's MAVLink: the socket, its fast reader, signing, and the sans-IO clients (commands, parameters,
missions, images)."""
