"""Cross-cutting helpers every package may use: errors, configuration, files, argument checks.

The bottom layer of the house (docs/architecture.md): it imports no other goflow package.
"""
