"""`make venv` installs with uv on the sources pip is configured for (tools/uv_pip.py)."""

from __future__ import annotations

import importlib.util
import os
import sys

from helpers.paths import REPO

_spec = importlib.util.spec_from_file_location("uv_pip", REPO / "tools" / "uv_pip.py")
uv_pip = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(uv_pip)


def _pairs(args: list[str], option: str) -> list[str]:
    return [args[k + 1] for k, a in enumerate(args) if a == option]


def test_pip_variables_reach_uv_over_pip_conf(monkeypatch, tmp_path):
    conf = tmp_path / "pip.conf"
    conf.write_text(
        "[global]\nindex-url = https://conf.invalid/simple\nfind-links = /conf/wheels\n"
        "cert = /conf/ca.pem\n[install]\nconstraint = /conf/site.txt\n"
    )
    for name in [n for n in os.environ if n.startswith("PIP_")]:
        monkeypatch.delenv(name)  # this machine's own settings
    monkeypatch.setenv("PIP_CONFIG_FILE", str(conf))  # read last: overrides the site's
    monkeypatch.setenv("PIP_INDEX_URL", "https://mirror.invalid/simple")
    monkeypatch.setenv("PIP_EXTRA_INDEX_URL", "file:///a/simple  file:///b/simple")
    args, env = uv_pip.uv_options(uv_pip.pip_settings(sys.executable))
    assert _pairs(args, "--index-url") == ["https://mirror.invalid/simple"]
    assert _pairs(args, "--extra-index-url") == ["file:///a/simple", "file:///b/simple"]
    assert _pairs(args, "--find-links") == ["/conf/wheels"]
    assert _pairs(args, "--constraint") == ["/conf/site.txt"]
    assert _pairs(args, "--index-strategy") == ["unsafe-best-match"]  # pip's: best of all
    assert env["SSL_CERT_FILE"] == "/conf/ca.pem"
    assert "--no-index" not in args


def test_no_index_is_kept():
    args, _ = uv_pip.uv_options({"no-index": "true", "find-links": "/w"})
    assert "--no-index" in args
    assert _pairs(args, "--find-links") == ["/w"]
    assert "--index-url" not in args
