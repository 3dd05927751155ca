"""trioman.toolkit: the torch side (body models, synthetic subjects, training).

This ``__init__`` imports nothing heavy so that command modules can be listed without torch.
"""
