using UnityEngine;

namespace Vista.Client.Unity
{
    /// <summary>Marks the GameObject of a defect node (<c>defect-&lt;id&gt;</c>) so that a tap on
    /// it (hand ray, gaze) can tell which defect was meant. Added by <see cref="SceneLoader"/>
    /// together with a collider.</summary>
    public sealed class DefectHandle : MonoBehaviour
    {
        /// <summary>The defect this node shows.</summary>
        public long DefectId { get; set; }
    }
}
