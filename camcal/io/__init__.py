"""Files in and out: RAW/image decoding, EXIF and time, EXR, manifests, stage files, the profile container,
atomic writes, read limits, hashing, bundled tables, the terminal and the process's allocator policy.

The only layer that touches files; it imports camcal's top-level core modules and nothing above.
"""
