"""Data camcal ships: small, cited reference tables, read with :func:`camcal.io.data.read_bundled_table`.

Files are loaded through :mod:`importlib.resources`, so they work from an
installed package as well as from a source checkout. Each CSV begins with
``#`` comment lines giving its source and units; ``README.md`` lists them.
"""
