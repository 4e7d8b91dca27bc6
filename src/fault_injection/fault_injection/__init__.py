"""Fault injection for the node graph: a relay that drops, delays, duplicates, reorders, freezes or
poisons the messages of one topic (see docs/reliability.md)."""
