"""The Refiner's and Examiner's training data and their training on it: the synthetic corpus (``build``, ``trioman
synth-corpus``; its options ``config``), the triplet files of one trained run (``triplets``, ``trioman triplets``;
``triplets_config``) and the corpus jobs that train the two models (``training``: ``fit_refiner``, ``fit_examiner``,
``trioman train-refiner`` / ``train-examiner``, whose options are ``toolkit/corpus_training_options.py``).

This ``__init__`` imports nothing, so that the commands build their parsers from the configs without torch.
"""
