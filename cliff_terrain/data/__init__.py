"""Synthetic fields the project generates itself (the demo input and the test oracles)."""
