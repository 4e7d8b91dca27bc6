"""Gait policies (learned and hand-tuned), the policy node and the offline trainer."""
