#!/bin/sh
# Print the path of a working Python X.Y interpreter, looking where a machine offers one:
#   tools/find_python.sh 3.13
# 1. pythonX.Y on the PATH, if it runs (a pyenv shim is on the PATH but fails when X.Y is not pyenv's active version);
# 2. pyenv's newest installed X.Y (pyenv latest), found through pyenv itself;
# 3. ${PYENV_ROOT:-~/.pyenv}/versions/X.Y*/bin/pythonX.Y, for a pyenv that is installed but not on the PATH.
# Exits 1 with what to install when there is none.
set -u
version=$1
name="python$version"
# Prints the interpreter's own path (not a shim's) when it runs and is X.Y.
found() {
    "$1" -c "import sys; assert '%d.%d' % sys.version_info[:2] == '$version'; print(sys.executable)" 2>/dev/null &&
        exit 0
}

if command -v "$name" >/dev/null 2>&1; then
    found "$name"
fi
if command -v pyenv >/dev/null 2>&1; then
    installed=$(pyenv latest "$version" 2>/dev/null) && found "$(pyenv root)/versions/$installed/bin/$name"
fi
for candidate in "${PYENV_ROOT:-$HOME/.pyenv}"/versions/"$version"*/bin/"$name"; do
    found "$candidate"
done
cat >&2 <<EOF
Python $version was not found (no working $name on the PATH, none under pyenv).
Install it, then run make again:
    pyenv install $version               # with pyenv
    apt-get install $name       # or from the system's packages, where they have it
or name an interpreter: make test PYTHON$(echo "$version" | tr -d .)=/path/to/$name
EOF
exit 1
