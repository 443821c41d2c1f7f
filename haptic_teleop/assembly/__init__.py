"""Assembly: a scene's parts built once, for every scene type, and the per-side tick and channel
that the engine and the live nodes both run (docs/architecture.md, "Layers")."""
