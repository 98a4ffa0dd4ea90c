"""Small in-memory caches of derived arrays (a kernel's spectrum, a registration's sampling maps):
one bounded store rule for every such cache in the package. The caches on disk are core/cache.py."""

from __future__ import annotations


def kept(cache: dict, entries: int, key, owner, build):
    """cache[key]'s value, built by `build()` where missing. owner: the object the value derives
    from, held in the entry and compared by identity, so a key holding id(owner) cannot be reused
    by another object while the entry lives (None for a key made of values alone). The oldest
    entry is dropped to keep at most `entries`."""
    hit = cache.get(key)
    if hit is None or hit[0] is not owner:
        if len(cache) >= entries:
            cache.pop(next(iter(cache)))
        hit = cache[key] = (owner, build())
    return hit[1]
