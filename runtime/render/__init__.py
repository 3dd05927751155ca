"""The numpy splat renderer (DESIGN.md semantics)."""
