"""Attributes that are views of a state record: the compiled kernels update one record (a numpy
array or a structured record) in place, and the Python object reads and assigns its rows or fields
through these properties instead of keeping copies."""

from __future__ import annotations


def view(record: str, key, doc: str, cast=None) -> property:
    """A property reading ``getattr(self, record)[key]`` (through ``cast`` when given, e.g. ``int``
    for a counter) and assigning into it in place."""

    def get(self):
        value = getattr(self, record)[key]
        return value if cast is None else cast(value)

    def put(self, value) -> None:
        getattr(self, record)[key] = value

    return property(get, put, doc=doc)
