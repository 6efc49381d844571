"""Barrett BH8-262 serial protocol (shared/reference/bh262_protocol.md)."""
