// depth.frag: the depth pre-pass of the VT pass (no colour).
void main() {}
