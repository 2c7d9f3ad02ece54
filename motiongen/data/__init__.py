"""Datasets: the on-disk format, source adapters, scenes and training windows."""
