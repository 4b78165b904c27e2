"""Validates a MaterialX document against MaterialX's own standard library (PyPI `MaterialX`),
as CI does (tests/exports_interop.rs). Exits 1 with MaterialX's message if it is not valid.
Usage: python scripts/validate-mtlx.py FILE"""
import sys

import MaterialX as mx

doc = mx.createDocument()
mx.readFromXmlFile(doc, sys.argv[1])
library = mx.createDocument()
mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), library)
doc.importLibrary(library)
valid, message = doc.validate()
print(f"MaterialX {mx.getVersionString()}: {'valid' if valid else 'not valid'} {message}")
sys.exit(0 if valid else 1)
