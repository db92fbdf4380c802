"""Planning: what a plan will teach before anything is measured, and the least chamber time to reach its
targets."""
