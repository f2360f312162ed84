"""Aiding sources (plugins) for shearer-fusion."""
