"""Synthetic subjects: body shape, procedural clothing, motions, cameras, mesh rendering."""
