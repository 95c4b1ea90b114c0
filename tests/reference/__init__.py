"""Tests of starnav.reference."""
