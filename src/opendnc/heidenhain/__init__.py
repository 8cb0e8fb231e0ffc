"""Heidenhain protocols that are not LSV2: the blockwise serial file protocol (FE modes)."""
