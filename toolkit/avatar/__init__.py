"""ExAvatar-style Gaussian avatar: one Gaussian per (optionally subdivided) body-mesh vertex."""
