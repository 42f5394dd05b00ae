"""The paper's network in PyTorch (training extra only: the robot-side path never imports it)."""
