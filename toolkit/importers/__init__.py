"""Importers: real captures (ExAvatar's layouts, fitter outputs) -> subject folders with an SMPL-X body."""
