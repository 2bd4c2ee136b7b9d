"""Configuration: the run config (``app``: ``AppConfig``, defaults, limits) and the checks every YAML loader uses
(``checks``: ``ConfigError`` naming the key and the problem). Import the submodules; this package imports nothing
(the checks are used by modules the run config itself imports)."""
