"""The exception hierarchy of the `edge` package: one base, subclasses that carry context."""

from __future__ import annotations


class EdgeError(Exception):
    """Base of every error this package raises on purpose."""


class InvalidDataError(EdgeError, ValueError):
    """An array or record does not have the shape, dtype or values a type requires."""

    def __init__(self, what: str, expected: str, got: object) -> None:
        self.what = what
        self.expected = expected
        self.got = got
        super().__init__(f"{what}: expected {expected}, got {got}")


class ConfigError(EdgeError, ValueError):
    """A configuration value is missing or out of range; names the key and what was expected."""

    def __init__(self, key: str, expected: str, got: object, source: str | None = None) -> None:
        self.key = key
        self.expected = expected
        self.got = got
        self.source = source
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{key}: expected {expected}, got {got!r}")

    def naming(self, source: str, section: str) -> ConfigError:
        """This error as raised from the config file `source`: a bare key (an engine or
        source option) gains its section, `engine.refine`; one that names a file already
        is returned as it is."""
        if self.source is not None:
            return self
        key = self.key if "." in self.key or self.key.startswith("-") else f"{section}.{self.key}"
        return ConfigError(key, self.expected, self.got, source)
