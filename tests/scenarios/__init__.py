"""Scenarios used only by the tests (registered by the tests themselves, never built in)."""
