"""mkdocs hook: links from the docs to files elsewhere in the repository.

The pages under `docs/` link to the repository's other files by their true relative paths
(`../benchmarks/results/flow/vortex.png`), so the links also work when the Markdown is read on a code host.
mkdocs sees only `docs/`, so this hook, for every such link:

- checks that the target exists in the repository, and warns if not (`mkdocs build --strict` then fails);
- serves images and videos (`ASSETS`) with the site, under `repo/<path in the repository>`, and points
  the link there;
- writes any other target (a folder, a JSON, a source file) as its path in code, `path/in/repo`, after the
  link's text: the site does not carry the repository.
"""

from __future__ import annotations

import logging
import os
import posixpath
import re

from mkdocs.structure.files import File

log = logging.getLogger("mkdocs.hooks.repo_links")

ASSETS = (".png", ".jpg", ".jpeg", ".gif", ".svg", ".mp4", ".webm")
SERVED = "repo"  # the site folder that holds the repository's assets
LINK = re.compile(r"(!?)\[([^\]]*)\]\(([^)\s]+)\)")
_assets: set[str] = set()


def _repo_root(config) -> str:
    return os.path.dirname(os.path.abspath(config["config_file_path"]))


def _docs_prefix(config) -> str:
    return os.path.relpath(config["docs_dir"], _repo_root(config)).replace(os.sep, "/")


def on_files(files, config):
    """Collects the assets that the pages link to and adds them to the site."""
    root, docs = _repo_root(config), _docs_prefix(config)
    wanted: set[str] = set()
    for file in files.documentation_pages():
        with open(file.abs_src_path, encoding="utf-8") as f:
            for target in _targets(f.read()):
                path = _repo_path(docs, file.src_uri, target)
                if path and path.lower().endswith(ASSETS) and os.path.isfile(os.path.join(root, path)):
                    wanted.add(path)
    _assets.clear()
    _assets.update(wanted)
    for path in sorted(wanted):
        files.append(File.generated(config, f"{SERVED}/{path}", abs_src_path=os.path.join(root, path)))
    return files


def on_page_markdown(markdown, page, config, files):
    root, docs = _repo_root(config), _docs_prefix(config)
    here = posixpath.dirname(page.file.src_uri)

    def rewrite(match: re.Match) -> str:
        bang, text, target = match.groups()
        path = _repo_path(docs, page.file.src_uri, target)
        if path is None:
            return match.group(0)
        if not os.path.exists(os.path.join(root, path)):
            log.warning("%s links to '%s', which is not in the repository", page.file.src_uri, path)
            return match.group(0)
        if path in _assets:
            anchor = target.partition("#")[2]
            url = posixpath.relpath(f"{SERVED}/{path}", here or ".") + (f"#{anchor}" if anchor else "")
            return f"{bang}[{text}]({url})"
        shown = path + ("/" if os.path.isdir(os.path.join(root, path)) else "")
        return text if text.strip("`") == shown or text.strip("`") == path else f"{text} (`{shown}`)"

    out, fenced = [], False
    for line in markdown.split("\n"):
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
        out.append(line if fenced else LINK.sub(rewrite, line))
    return "\n".join(out)


def _targets(markdown: str):
    fenced = False
    for line in markdown.split("\n"):
        if line.lstrip().startswith(("```", "~~~")):
            fenced = not fenced
        elif not fenced:
            for match in LINK.finditer(line):
                yield match.group(3)


def _repo_path(docs: str, src_uri: str, target: str) -> str | None:
    """The repository path of a relative link that leaves the docs folder, else None."""
    if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith(("#", "/")):
        return None
    target = target.partition("#")[0]
    if not target:
        return None
    path = posixpath.normpath(posixpath.join(docs, posixpath.dirname(src_uri), target))
    if path == docs or path.startswith((docs + "/", "..")):
        return None
    return path
