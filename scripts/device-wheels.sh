# Sourced by the device-machine commands (scripts/device-grid.sh, scripts/device-report.sh): the
# packages the device image lacks travel as py3.12 wheels in .whl (ignored by git, named in the
# call's carry), 41 MB: the runtime's mcap, lz4, zstandard and Foxglove schemas, and matplotlib
# with what it needs, for the report's figures. Made here, before the call, with
#   echo /.whl/ >> .git/info/exclude
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#     --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
#     -d .whl mcap mcap-protobuf-support foxglove-schemas-protobuf lz4 zstandard \
#     matplotlib contourpy cycler fonttools kiwisolver pillow pyparsing python-dateutil tzdata packaging \
#     pytest pluggy iniconfig onnx
# (pytest, pluggy, iniconfig and onnx, 9 MB: the tests marked cuda that scripts/device-grid.sh
# runs first; the matplotlib group, 24 MB, serves only the report's figures.) They are installed
# into /tmp/site, first on PYTHONPATH, only when one of those packages does not import.
if [ -d .whl ] && ! python3 -c 'import mcap_protobuf, foxglove_schemas_protobuf, matplotlib, pytest, onnx' 2>/dev/null; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
    export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
fi
