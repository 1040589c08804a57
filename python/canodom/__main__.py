"""`python -m canodom` lists what the package offers."""
print(__import__("canodom").__doc__)
