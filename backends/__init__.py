from solver.moved import alias_moved_modules

# The robot's body and collision checker serve the agent too, not only the mock: body.nao_body. Until the next
# release the old name still imports.
alias_moved_modules({"backends.pybullet_body": "body.nao_body"})
