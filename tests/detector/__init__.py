"""Tests of starnav.detector."""
