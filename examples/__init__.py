"""The runnable examples, installed with ncgate as package data (``ncgate examples``)."""
