"""Body models behind one small interface (see ``base.BodyModel``), created by name."""
