"""The aiding plugins shipped with shearer-fusion, registered under the entry-point group
``fusion.plugins`` (pyproject.toml)."""
