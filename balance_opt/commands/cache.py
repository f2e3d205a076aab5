"""``cache``: the folder of compiled artefacts, its entries, their clearing."""

from __future__ import annotations

import datetime
import os

from balance_opt.commands.common import EXIT_OK, count


def cmd_cache(args) -> int:
    from balance_opt import cache

    folder, env, size = cache.default_cache_dir(), cache.CACHE_ENV, cache.format_size
    origin = f"${env}" if os.environ.get(env) else f"default; set ${env}"
    print(f"cache folder: {folder} ({origin})")
    if not folder.is_dir():
        print("empty (the folder does not exist yet)")
        return EXIT_OK
    if args.clear:
        deleted, kept = cache.clear(folder)
        freed = size(sum(e.size for e in deleted))
        print(f"deleted {count(len(deleted), 'entry', 'entries')} ({freed})")
        for entry in kept:
            print(f"kept {entry.name}: a build under way in another process")
        return EXIT_OK
    found = cache.entries(folder)
    total = sum(e.size for e in found)
    print(f"size: {size(total)} (bound {size(cache.size_limit())}, ${cache.LIMIT_ENV})")
    for kind in cache.KINDS:
        group = [e for e in found if e.kind == kind]
        if not group:
            continue
        print(
            f"{kind}: {count(len(group), 'entry', 'entries')}, {size(sum(e.size for e in group))}"
        )
        if not args.list:
            continue
        for e in group:
            used = datetime.datetime.fromtimestamp(e.last_used).strftime("%Y-%m-%d %H:%M")
            print(f"  {e.name}  {size(e.size)}  last used {used}")
    if found and not args.list:
        print("--list shows every entry")
    return EXIT_OK
