from penfree.cli import main

main()
