"""What a flight records: the recorder on the traffic, the recording's data model, metrics, the tlog."""
