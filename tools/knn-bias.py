#!/usr/bin/env python3
"""The k-NN Epanechnikov density estimate's mean on uniform 2-D point sets of three kinds.

Normalised by the K-th neighbour's distance r_K, the estimate 2/(pi r_K^2) * sum(1 - d^2/r_K^2)
is unbiased for a Poisson set (E[1/(pi r_K^2)] = rho/(K-1) and the K-1 points inside average
1/2 of the kernel), but not for stratified sets, whose K-th neighbour distance varies less:
traced photons (Halton emission) and relaxed photons are such sets. Prints mean(estimate)/rho - 1
for r_K and for r^2 = (r_K^2 + r_{K+1}^2)/2. Needs numpy and scipy. See docs/truth.md.
"""
import numpy as np
from scipy.spatial import cKDTree
rng=np.random.default_rng(1)
N=200000; K=15
def halton(n,b):
    out=np.zeros(n); 
    for i in range(n):
        f=1;r=0;k=i+1
        while k>0:
            f/=b; r+=f*(k%b); k//=b
        out[i]=r
    return out
sets={'poisson':rng.random((N,2))}
g=int(np.sqrt(N)); xs=(np.arange(g)[:,None]+rng.random((g,g)))/g; ys=(np.arange(g)[None,:]+rng.random((g,g)))/g
sets['jitter']=np.stack([xs.ravel(),ys.ravel()],1)
sets['halton']=np.stack([halton(N,2),halton(N,3)],1)
q=0.1+0.8*rng.random((20000,2))
for name,P in sets.items():
    n=len(P); t=cKDTree(P); d,_=t.query(q,K+1)
    for label,r2 in [('rK',d[:,K-1]**2),('mid',(d[:,K-1]**2+d[:,K]**2)/2)]:
        w=np.where(d[:,:K]**2<=r2[:,None],1-d[:,:K]**2/r2[:,None],0)
        est=(2/(np.pi*r2))*w.sum(1)/n
        print(name,label,round(est.mean()-1,4))
