def compile_joints(model, builder):
    return None
