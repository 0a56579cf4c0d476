"""``smplik edit``: the interactive pose editor (state model, viser front end, skinning, export)."""
