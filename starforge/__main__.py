from starforge.cli import main

main()
