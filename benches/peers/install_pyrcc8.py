"""Installs PyRCC8 1.2.2 (Sioutis, 2012), the RCC-8 peer of rcc8_peers.py, into this Python's env.

usage: benches/.venv/bin/python benches/peers/install_pyrcc8.py

PyRCC8 is on PyPI as project `pyrcc8`, but its only files (PyRCC8v.1.2.2.tar.gz, PyRCC8.tar.gz)
are bare Python 2 script folders whose names carry no parsable version and that have no setup.py,
so `pip install pyrcc8` finds "no versions". This script:
  1. reads the project's page on the package index pip uses (PIP_INDEX_URL, else pip's default),
     takes the link to PyRCC8v.1.2.2.tar.gz and checks it against the pinned sha256 below;
  2. ports the modules to Python 3 with the standard library's lib2to3 (default fixers: print,
     xrange, reduce, map -> list(map(...)), implicit sibling imports -> relative imports), and
     drops rcc8.py's call to sys.setcheckinterval (gone since Python 3.9);
  3. wraps them as the package `pyrcc8` (version 1.2.2) in a wheel and installs that with this
     env's pip.
The algorithm is untouched: rcc8_peers.py times pyrcc8.pc.PC, van Beek's queue-based path
consistency over 8-bit relation codes with precomputed composition/intersection/inverse tables.
Does nothing if `pyrcc8` 1.2.2 is already installed (pass --force to redo).
"""
import base64
import hashlib
import html.parser
import io
import os
import pathlib
import subprocess
import sys
import tarfile
import tempfile
import urllib.parse
import urllib.request
import zipfile

FILENAME = "PyRCC8v.1.2.2.tar.gz"
SHA256 = "01682010cc21f811a7a0895c183fea2e0e1fde9accb2eaa8e797c0e33fbeec93"
VERSION = "1.2.2"


def installed():
    try:
        from importlib.metadata import version
        return version("pyrcc8") == VERSION
    except Exception:
        return False


class Links(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.hrefs = []

    def handle_starttag(self, tag, attrs):
        if tag == "a":
            self.hrefs += [v for k, v in attrs if k == "href"]


def index_url():
    url = os.environ.get("PIP_INDEX_URL")
    if not url:
        from pip._internal.models.index import PyPI
        url = PyPI.simple_url
    return url.rstrip("/")


def fetch(url):
    with urllib.request.urlopen(url, timeout=180) as r:
        return r.read()


def download():
    page_url = index_url() + "/pyrcc8/"
    parser = Links()
    parser.feed(fetch(page_url).decode())
    for href in parser.hrefs:
        url = urllib.parse.urljoin(page_url, href)
        if urllib.parse.urlparse(url).path.endswith("/" + FILENAME):
            data = fetch(url.split("#")[0])
            got = hashlib.sha256(data).hexdigest()
            if got != SHA256:
                sys.exit(f"{FILENAME}: sha256 {got}, expected {SHA256}")
            return data
    sys.exit(f"{FILENAME} not listed on {page_url}")


def write_wheel(whl, pkg):
    """A pure-Python wheel written directly (the env need not have setuptools or wheel)."""
    dist = f"pyrcc8-{VERSION}.dist-info"
    files = {f"pyrcc8/{p.name}": p.read_bytes() for p in sorted(pkg.glob("*.py"))}
    files[f"{dist}/METADATA"] = (
        f"Metadata-Version: 2.1\nName: pyrcc8\nVersion: {VERSION}\n"
        "Summary: PyRCC8 1.2.2 (RCC8 qualitative spatial reasoner, M. Sioutis), Python 3 port\n").encode()
    files[f"{dist}/WHEEL"] = (
        "Wheel-Version: 1.0\nGenerator: install_pyrcc8.py\nRoot-Is-Purelib: true\nTag: py3-none-any\n").encode()
    record = []
    for name, data in files.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
        record.append(f"{name},sha256={digest},{len(data)}")
    record.append(f"{dist}/RECORD,,")
    files[f"{dist}/RECORD"] = ("\n".join(record) + "\n").encode()
    with zipfile.ZipFile(whl, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            z.writestr(name, data)


def main():
    if installed() and "--force" not in sys.argv:
        print(f"pyrcc8 {VERSION} already installed")
        return
    data = download()
    with tempfile.TemporaryDirectory() as tmp:
        root = pathlib.Path(tmp)
        pkg = root / "pyrcc8"
        pkg.mkdir()
        with tarfile.open(fileobj=io.BytesIO(data)) as tar:
            for m in tar.getmembers():
                p = pathlib.PurePosixPath(m.name)
                if m.isfile() and p.suffix == ".py" and len(p.parts) == 2 and p.parts[0] == "PyRCC8":
                    (pkg / p.name).write_bytes(tar.extractfile(m).read())
        (pkg / "__init__.py").write_text('"""PyRCC8 1.2.2 (M. Sioutis), ported to Python 3 by lib2to3."""\n')
        r = subprocess.run([sys.executable, "-W", "ignore", "-m", "lib2to3", "-w", "-n", "--no-diffs",
                            str(pkg)], capture_output=True, text=True)
        if r.returncode:
            sys.exit(f"lib2to3 failed:\n{r.stderr}")
        rcc8 = pkg / "rcc8.py"
        rcc8.write_text(rcc8.read_text().replace("sys.setcheckinterval(10000)", "pass"))
        pc = (pkg / "pc.py").read_text()
        assert "list(map(add_task" in pc and "from .comptab import fcomp" in pc, "port check failed"
        whl = root / f"pyrcc8-{VERSION}-py3-none-any.whl"
        write_wheel(whl, pkg)
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-index", "--force-reinstall",
                        str(whl)], check=True)
    print(f"installed pyrcc8 {VERSION}")


if __name__ == "__main__":
    main()
