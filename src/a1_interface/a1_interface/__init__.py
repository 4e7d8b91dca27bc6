"""The stack's message contract (see contract.py); no simulator in it."""
