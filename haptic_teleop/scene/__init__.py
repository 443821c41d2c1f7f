"""Scenes: YAML -> validated, frozen config (`schema`), `--set` overrides (`overrides`), reading,
checking against the models and finding bundled scenes (`load`). docs/scenes.md "Scenes" says where
every key is declared."""
