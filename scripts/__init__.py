"""Thin command-line entry points (train, compare, benchmark, diagnose, demo)."""
