#!/usr/bin/env bash
# Builds GQR (Gantner, Westphal, Wölfl; GPL-2.0) from a checkout beside the project, for the
# RCC-8 benchmark's side-by-side column. Never committed: the binary and the calculus files go
# to benches/.gqr (ignored). GQR's own build uses waf under Python 2; its sources need only a
# C++ compiler, so they are compiled directly with the flags of its wscript (-O3 -DNDEBUG).
#   GQR_SRC=/path/to/gqr-checkout benches/peers/build_gqr.sh
# A git mirror (as `fetch github:m-westphal/gqr` leaves) works too: GQR_SRC=/path/to/repo.git
set -euo pipefail
cd "$(dirname "$0")/../.."
out=benches/.gqr
src="${GQR_SRC:?set GQR_SRC to a GQR checkout or git directory}"
rm -rf "$out/src" && mkdir -p "$out/src"
if [ -d "$src/gqr" ]; then
  cp -r "$src/gqr" "$src/data" "$out/src/"
else
  # A bare git directory: take what the build and the RCC-8 calculus need.
  git -C "$src" archive HEAD gqr data/rcc8 data/rcc8.spec | tar -x -C "$out/src"
fi
cd "$out/src/gqr"
printf '#define GQR_DEFAULT_DATA_DIR "%s"\n' "$PWD/../data" > config.h
g++ -std=gnu++98 -O3 -DNDEBUG -w -I. -I.. -DGQR_VERSION='"1501"' \
  utils/Timer.cpp utils/Logger.cpp Stringtools.cpp gqr.cpp PriorityQueue.cpp Calculus.cpp \
  CalculusReader.cpp CombinedCalculusReader.cpp CSPReader.cpp FileSplitter.cpp \
  RestartsFramework.cpp commands/SubcommandAbstract.cpp commands/SubcommandHelp.cpp \
  commands/SubcommandVersion.cpp commands/SubcommandCheck.cpp \
  commands/SubcommandPathConsistency.cpp commands/SubcommandConsistency.cpp \
  -o ../../gqr
echo "built $(cd ../.. && pwd)/gqr (run it with GQR_DATA_DIR=$(cd .. && pwd)/data)"
