"""Placeholder replaced below."""
def compile_contacts(model, builder):
    return None
