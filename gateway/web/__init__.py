"""The commissioning console (aiohttp): see console.py."""
