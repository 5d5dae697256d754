"""The fuzz table passes strings such as "bogus" where a path is expected; a save function may
accept one as a valid relative path, so every case runs in a fresh working directory instead of
writing into the checkout."""

import pytest


@pytest.fixture(autouse=True)
def _run_in_tmp_cwd(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
