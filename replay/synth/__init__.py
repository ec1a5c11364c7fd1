"""Synthetic bin-picking scans with exact ground truth (paper Figure 8 parts, Zivid-like sensor)."""
