"""One strict builder of a dataclass from a mapping (config sections, case dicts, checkpoints).

Unknown keys are an error that names them and the known ones; a key renamed since an older
version is an error that names its new spelling, so an old config or file fails loudly, not
silently with a default.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import TypeVar

T = TypeVar("T")


def from_mapping(
    cls: type[T], data: Mapping, error: type[Exception], where: str, renamed: Mapping[str, str] | None = None
) -> T:
    """cls(**data) after checking every key of `data` is a field of `cls`.

    error: the exception type raised; where: what `data` is, for the message (e.g. "config gns");
    renamed: {old key: new key} of keys renamed in earlier versions.
    """
    known = [f.name for f in dataclasses.fields(cls)]
    unknown = set(data) - set(known)
    old = sorted(unknown & set(renamed or {}))
    if old:
        raise error(f"{where}: renamed key(s): " + "; ".join(f"{k} is now {renamed[k]}" for k in old))
    if unknown:
        raise error(f"{where}: unknown key(s) {sorted(unknown)}; known: {sorted(known)}")
    return cls(**data)
