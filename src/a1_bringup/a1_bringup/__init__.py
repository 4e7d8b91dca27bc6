"""The node graph described once (graph.py)."""
