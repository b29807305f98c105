import os

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def pytest_collection_modifyitems(config, items):
    """The tests marked ``slow`` first, then the rest, so that under ``pytest -n 2 --dist load --maxschedchunk 2``
    (``make test``) the long checks start early on both workers and the short ones fill in around them, instead of
    a long check starting last while the other worker idles. The slow tests of the folders whose checks take
    longest come first, taken in turn from each folder: two workers rarely wait on the same shared study."""
    order = ("study", "world", "play")

    def folder(item) -> int:
        parts = item.path.relative_to(config.rootpath).parts  # ("tests", "study", "test_x.py"), ("pernav", ...)
        name = parts[1] if parts[0] == "tests" and len(parts) > 2 else ""
        return order.index(name) if name in order else len(order)

    slow = [item for item in items if item.get_closest_marker("slow") is not None]
    groups = [[item for item in slow if folder(item) == k] for k in range(len(order) + 1)]
    turns = [group[i] for i in range(max(map(len, groups))) for group in groups if i < len(group)]
    items[:] = turns + [item for item in items if item.get_closest_marker("slow") is None]
