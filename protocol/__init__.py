"""The CAN contract between nodes: DBC, end-to-end protection, codec, bus selection."""
