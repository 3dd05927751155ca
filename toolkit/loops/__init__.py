"""What every training loop shares (docs/design.md, "Conventions"): atomic checkpoints (``checkpoint``), the
non-finite guard (``guard``) and a model's run in a run folder, resumed, shown and checkpointed (``model_run``).
The loops themselves live with what they train (``toolkit.train.loop``, the avatar's; ``toolkit.refiner.loop``;
``toolkit.examiner.loop``)."""
