"""Reading the YAML files a user gives (scenario files, ``recording.yaml``, calibrations) with bounded work.

A YAML file is text of at most :data:`MAX_YAML_BYTES`; its aliases (``*name``, which repeat an anchored
node) may add at most :data:`MAX_ALIAS_NODES` nodes to what is written out, so a "billion laughs" file
(anchors of anchors, each repeated) is refused while it is parsed, before anything walks the repeated
structure. Every refusal is one :class:`~softsbi.core.errors.DataError` line naming the file and the fix.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from softsbi.core.errors import DataError

#: largest YAML file read (bytes): scenario files and recordings hold settings and short paths; long paths
#: and clouds belong in ``.npy`` files beside them
MAX_YAML_BYTES = 4 * 2**20
#: most nodes the aliases of one file may add to it (an alias counts as the size of the node it repeats)
MAX_ALIAS_NODES = 100_000


def read_yaml(path: str | Path, hint: str = "fix that line") -> Any:
    """The data of the YAML file ``path`` (PyYAML's safe loader: plain data only, no Python tags).

    Args:
        hint: the fix named in the message of a syntax error.

    Raises:
        DataError: the file is larger than :data:`MAX_YAML_BYTES`, not UTF-8 text, not valid YAML, or its
            aliases expand by more than :data:`MAX_ALIAS_NODES` nodes.
        OSError: the file cannot be read (missing, a directory): the caller names what it expected.
    """
    path = Path(path)
    size = path.stat().st_size
    if size > MAX_YAML_BYTES:
        raise DataError(f"{path} is {size / 2**20:.1f} MB, over the {MAX_YAML_BYTES // 2**20} MB a YAML file may "
                        f"have; give long arrays as .npy files beside it")
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path} is not a text file (byte {exc.start} is not UTF-8); give the YAML file "
                        f"itself") from None
    return load_yaml(text, str(path), hint)


def load_yaml(text: str, source: str, hint: str = "fix that line") -> Any:
    """:func:`read_yaml` for text already read; ``source`` names it in messages."""
    class Loader(yaml.SafeLoader):
        """The safe loader, counting what aliases add while it composes the document."""

        def __init__(self, stream: str):
            super().__init__(stream)
            self.sizes: dict[int, int] = {}  # id(node) -> nodes it stands for, its aliases expanded
            self.added = 0

        def compose_node(self, parent: Any, index: Any) -> Any:
            alias = self.check_event(yaml.AliasEvent)
            node = super().compose_node(parent, index)
            if alias:
                self.added += self.sizes.get(id(node), 1)  # (a node still being composed: a recursive alias)
                if self.added > MAX_ALIAS_NODES:
                    raise DataError(f"{source}: its aliases (*name) repeat more than {MAX_ALIAS_NODES} nodes, as a "
                                    f"YAML bomb does; write the values out or use fewer aliases")
            elif id(node) not in self.sizes:
                kids = node.value if isinstance(node, yaml.SequenceNode) else (
                    [n for kv in node.value for n in kv] if isinstance(node, yaml.MappingNode) else [])
                self.sizes[id(node)] = 1 + sum(self.sizes.get(id(k), 1) for k in kids)
            return node

    loader = Loader(text)
    try:
        return loader.get_single_data()
    except yaml.YAMLError as exc:
        at, problem = _error_parts(exc)
        raise DataError(f"{source} is not valid YAML{at} ({problem}); {hint}") from None
    finally:
        loader.dispose()


def _error_parts(exc: BaseException) -> tuple[str, str]:
    """Where and what of a PyYAML parse error, for a one-line message.

    Returns:
        ``(" at line L, column C", problem)``: the location (1-based; ``""`` when the parser gave
        none) and the parser's short description (its first line when it gave no ``problem``).
    """
    mark = getattr(exc, "problem_mark", None)
    at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return at, getattr(exc, "problem", None) or str(exc).splitlines()[0]
