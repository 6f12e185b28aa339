"""gsplat's first load on a machine builds its CUDA extension and prints its progress with rich on
standard output, where `--json` writes its document. A stand-in gsplat that prints as gsplat's
_backend does (Console().print at import) shows where that output goes, without a GPU."""

import sys

from lumos3d_cli.render import gsplat_backend


def test_the_first_load_of_gsplat_prints_nothing_on_standard_output(tmp_path, monkeypatch, capsys):
    package = tmp_path / "gsplat"
    (package / "cuda").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "cuda" / "__init__.py").write_text("")
    (package / "cuda" / "_backend.py").write_text(
        "from rich.console import Console\n"
        "Console().print('gsplat: CUDA extension has been set up successfully in 60.35 seconds.')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in [name for name in sys.modules if name == "gsplat" or name.startswith("gsplat.")]:
        monkeypatch.delitem(sys.modules, name)
    gsplat_backend._loaded_gsplat.cache_clear()
    try:
        module = gsplat_backend._loaded_gsplat()
        assert module.__file__ == str(package / "__init__.py")
        captured = capsys.readouterr()
        assert captured.out == "" and "set up successfully" in captured.err
    finally:
        gsplat_backend._loaded_gsplat.cache_clear()
        for name in [name for name in sys.modules if name == "gsplat" or name.startswith("gsplat.")]:
            del sys.modules[name]
