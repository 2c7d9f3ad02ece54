"""Exports of generated or imported motion (BVH; npz and video live beside it)."""
