"""``rig.toml``: one module per section, the schema that validates it, the criteria defaults."""
