"""Look at a restored scene: the interactive browser viewer (viser) and orbit videos."""
